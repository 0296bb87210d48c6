"""The Python package against the C++ engine: events in, layers out, snapshots that do not
change under a writing engine, .tmap round trips, the simulator source and the FEE."""
import json
import os
import subprocess

import numpy as np
import pytest

import terramap

SOURCE_DIR = os.environ.get("TERRAMAP_SOURCE_DIR", os.path.join(os.path.dirname(__file__), "..", ".."))
BINARY_DIR = os.environ.get("TERRAMAP_BINARY_DIR", os.path.join(SOURCE_DIR, "build"))
# PROBE_YAML names the test plugins' folder: these tests trust their own files.
terramap.allow_config_plugin_paths(True)

PROBE_YAML = """version: 1
map: {resolution: 0.1, size: [40, 30], tile: 16, layers: [{name: elevation, unit: m}]}
threads: 2
plugin_paths: [%s]
source: {type: none}
pipeline:
  - {name: probe, type: test_probe, params: {increment: 0.5, events: [tick]}}
""" % os.path.join(BINARY_DIR, "test_plugins")

FUSION_YAML = """version: 1
map: {resolution: 0.2, size: [50, 50], center: [5, 0]}
threads: 2
source: {type: none}
pipeline:
  - {name: lidar, type: lidar_fusion, params: {min_range_m: 0.5, max_range_m: 30}}
"""


def identity():
    return np.eye(4)


def test_layers_come_out_in_logical_order_and_match_the_tiles():
    eng = terramap.Engine.from_yaml(PROBE_YAML)
    for k in range(3):
        eng.push_tick(0.1 * k)
    snap = eng.snapshot()
    probe = snap.layer("probe")
    assert probe.shape == (40, 30) and probe.dtype == np.float32
    assert np.all(probe == 1.5)  # three ticks of +0.5
    # Every tile view is the same memory the layer was copied from (the map has not moved, so
    # buffer order is logical order).
    assert snap.start_index == (0, 0)
    for t in range(snap.tile_count):
        r = snap.tile_rect(t)
        view = snap.tile("probe", t)
        assert view.shape == (r["rows"], r["cols"])
        np.testing.assert_array_equal(view, probe[r["row"]:r["row"] + r["rows"], r["col"]:r["col"] + r["cols"]])


def test_tile_views_are_zero_copy_read_only_and_survive_later_writes():
    eng = terramap.Engine.from_yaml(PROBE_YAML)
    eng.push_tick(0.0)
    snap = eng.snapshot()
    a, b = snap.tile("probe", 0), snap.tile("probe", 0)
    assert np.shares_memory(a, b)  # both views are the snapshot's tile, not copies
    assert not a.flags.writeable
    with pytest.raises(ValueError):
        a[0, 0] = 7
    before = a.copy()
    del snap  # the view alone keeps the snapshot's memory alive
    for k in range(5):
        eng.push_tick(1.0 + k)  # the engine copies the shared tile before writing it
    np.testing.assert_array_equal(a, before)
    assert np.all(eng.snapshot().layer("probe") == 3.0)


def test_a_flat_ground_cloud_is_fused_at_its_height():
    eng = terramap.Engine.from_yaml(FUSION_YAML)
    rng = np.random.default_rng(1)
    xy = rng.uniform([1, -4], [9, 4], size=(20000, 2))
    sensor_z = 1.5  # sensor 1.5 m above ground at z = 0.25 in the map frame
    pts = np.column_stack([xy, np.full(len(xy), -sensor_z), np.ones(len(xy))]).astype(np.float64)
    T = identity()
    T[2, 3] = 0.25 + sensor_z
    eng.push_cloud(pts, T, 0.0)
    h = eng.snapshot().layer("elevation")
    known = h[np.isfinite(h)]
    assert known.size > 1000
    np.testing.assert_allclose(known, 0.25, atol=1e-4)
    report = eng.report()
    lidar = [s for s in report["stages"] if s["name"] == "lidar"][0]
    assert lidar["counters"]["points_in"] == 20000


def test_bad_input_raises_with_its_context():
    with pytest.raises(terramap.ConfigError, match=r"<python>:\d+:\d+.*incremnt"):
        terramap.Engine.from_yaml(PROBE_YAML.replace("increment", "incremnt"))
    eng = terramap.Engine.from_yaml(PROBE_YAML)
    with pytest.raises(ValueError, match="N x 3"):
        eng.push_cloud(np.zeros((5, 2)), identity(), 0.0)
    bad = identity()
    bad[0, 0] = 2.0
    with pytest.raises(ValueError, match="rigid"):
        eng.push_pose(bad, 0.0)
    with pytest.raises(terramap.LayerError, match="elevaton"):
        eng.snapshot().layer("elevaton")
    with pytest.raises(terramap.InputError):
        terramap.load_snapshot(os.path.join(SOURCE_DIR, "README.md"))


def test_a_pipeline_names_plugin_folders_only_when_allowed():
    terramap.allow_config_plugin_paths(False)
    try:
        with pytest.raises(terramap.ConfigError, match=r"<python>:\d+:\d+: plugin_paths: .*allow_config_plugin_paths"):
            terramap.Engine.from_yaml(PROBE_YAML)
    finally:
        terramap.allow_config_plugin_paths(True)
    assert terramap.Engine.from_yaml(PROBE_YAML).stage_names == ["probe"]


def test_snapshot_files_round_trip(tmp_path):
    eng = terramap.Engine.from_yaml(PROBE_YAML)
    eng.push_tick(0.0)
    snap = eng.snapshot()
    path = tmp_path / "m.tmap"
    snap.save(str(path))
    back = terramap.load_snapshot(str(path))
    assert back.layer_names == snap.layer_names
    assert back.geometry.size == (40, 30) and back.geometry.resolution == pytest.approx(0.1)
    for name in snap.layer_names:
        np.testing.assert_array_equal(back.layer(name), snap.layer(name))
    assert back.layer_info("probe")["unit"] == "1"


def test_the_simulator_source_plays_and_knows_the_truth(tmp_path):
    # The demo with perfect localisation: what is under test is the binding's truth comparison,
    # and its RMSE sanity bound is that of the mapper with exact poses (the realistic default's
    # pose error is measured in docs/sim.md, "Localisation").
    scenario = open(os.path.join(SOURCE_DIR, "configs", "scenarios", "dense_strip.yaml")).read()
    (tmp_path / "scenario.yaml").write_text(scenario + "localisation: perfect\n")
    yaml = open(os.path.join(SOURCE_DIR, "configs", "demo.yaml")).read()
    assert "scenario: scenarios/dense_strip.yaml" in yaml
    yaml = yaml.replace("scenario: scenarios/dense_strip.yaml", "scenario: scenario.yaml")
    # Paths are relative to base_dir (the copy's folder): the demo reads no other file.
    assert "../models/" not in yaml
    eng = terramap.Engine.from_yaml(yaml, base_dir=str(tmp_path), threads=2)
    n = eng.play(max_events=400)
    assert n == 400
    n += eng.play()  # the rest
    eng.finish()
    truth = eng.compare_with_truth()
    assert truth["cells_compared"] > 0.9 * truth["cells_with_truth"]
    assert truth["rmse_m"] < 0.05
    # The RMSE from the two independent layers (the map's elevation and the truth sampled at the
    # cell centres), not from the error layer the same comparison wrote.
    snap = eng.snapshot()
    diff = snap.layer("elevation").astype(np.float64) - snap.layer("truth_elevation").astype(np.float64)
    both = np.isfinite(diff)
    assert both.sum() == truth["cells_compared"]
    np.testing.assert_allclose(np.sqrt(np.mean(diff[both] ** 2)), truth["rmse_m"], rtol=1e-5)


@pytest.mark.skipif(not hasattr(terramap, "Strata"), reason="built without OctoMap")
def test_a_saved_strata_model_answers_soil_queries(tmp_path):
    # configs/strata.yaml for its first two passes (25 s), the model saved into tmp_path.
    yaml = open(os.path.join(SOURCE_DIR, "configs", "strata.yaml")).read()
    for old, new in [("scenario: scenarios/strata_loam_over_clay.yaml",
                      "scenario: " + os.path.join(SOURCE_DIR, "configs", "scenarios", "strata_loam_over_clay.yaml")
                      + ", max_time_s: 25"),
                     ("model: ../models/soil_pinn.pt", "model: " + os.path.join(SOURCE_DIR, "models", "soil_pinn.pt")),
                     ("save_path: ../out/strata/strata.ot", "save_path: strata.ot"),
                     ("octovis_path: ../out/strata/strata_octovis.ot", "octovis_path: ''"),
                     ("section_png: ../out/strata/section_c.png", "section_png: ''")]:
        assert old in yaml, old
        yaml = yaml.replace(old, new)
    eng = terramap.Engine.from_yaml(yaml, base_dir=str(tmp_path), threads=2)
    eng.play()
    eng.finish()
    s = terramap.Strata.load(str(tmp_path / "strata.ot"))
    assert s.columns > 1000 and s.resolution == pytest.approx(0.05)
    # The lane runs from x = 0 towards -4 m at y = 0: a cut column there.
    top, first = s.surface_at(-1.5, 0.0), s.initial_surface_at(-1.5, 0.0)
    assert np.isfinite(top) and first > top
    removed = s.soil_at(-1.5, 0.0, 0.5 * (top + first))
    assert removed["source"] in ("removed", "predicted") and np.all(np.isfinite(removed["mean"]))
    below = s.soil_at(-1.5, 0.0, top - 0.3)
    assert below["source"] in ("inherited", "prior") and below["var"][0] > 0
    assert s.soil_at(-1.5, 0.0, first + 0.5)["source"] == "air"
    assert s.soil_at(15.0, 5.0, 0.0)["source"] == "prior"  # never cut: the configured prior
    assert s.soil_at(100.0, 0.0, 0.0)["source"] == "outside"
    nxt = s.expected_cut(-1.5, 0.0, 0.2)
    assert np.all(np.isfinite(nxt["mean"]))
    with pytest.raises(terramap.InputError, match="strata.yaml"):
        terramap.Strata.load(os.path.join(SOURCE_DIR, "configs", "strata.yaml"))


def test_fee_equals_the_command_line_calculator():
    args = dict(c_pa=5000.0, phi_rad=np.radians(30), gamma_n_m3=18000.0, ca_pa=2000.0, delta_rad=np.radians(20),
                alpha_rad=np.radians(5), rho_rad=np.radians(80), d_m=0.15, w_m=1.85, q_n=300.0)
    r = terramap.fee(**args)
    assert r["valid"] and r["validity"] == "Valid"
    cli = subprocess.run(
        [os.path.join(BINARY_DIR, "bin", "terramap"), "fee", "--c-pa", "5000", "--phi-deg", "30", "--gamma-n-m3",
         "18000", "--ca-pa", "2000", "--delta-deg", "20", "--alpha-deg", "5", "--rho-deg", "80", "--d-m", "0.15",
         "--w-m", "1.85", "--q-n", "300"], capture_output=True, text=True, check=True)
    ref = json.loads(cli.stdout)
    assert r["f_N"] == pytest.approx(ref["f_N"], rel=1e-12)
    assert r["beta_rad"] == pytest.approx(ref["beta_rad"], rel=1e-12)
    # At another failure angle the force changes (the argument is used).
    assert terramap.fee(**args, beta_rad=r["beta_rad"] + 0.1)["f_N"] != pytest.approx(r["f_N"])


def test_help_is_useful():
    doc = terramap.__doc__
    for word in ("snapshot", "layer(", "tile(", "NaN", "metres"):
        assert word in doc
    assert "push_cloud" in terramap.Engine.__doc__


def test_a_single_tile_map_gives_the_whole_layer_zero_copy():
    eng = terramap.Engine.from_yaml(PROBE_YAML.replace("tile: 16", "tile: 64"))
    eng.push_tick(0.0)
    snap = eng.snapshot()
    view = snap.layer_view("probe")
    assert view.shape == (40, 30) and not view.flags.writeable
    assert np.shares_memory(view, snap.tile("probe", 0))
    np.testing.assert_array_equal(view, snap.layer("probe"))
    eng.push_tick(1.0)
    assert np.all(view == 0.5)  # the snapshot's view, not the engine's newer map
    tiled = terramap.Engine.from_yaml(PROBE_YAML)
    tiled.push_tick(0.0)
    with pytest.raises(ValueError, match="tiles"):
        tiled.snapshot().layer_view("probe")


def test_a_pipeline_built_in_code_runs_like_one_from_yaml():
    plugins = os.path.join(BINARY_DIR, "test_plugins")
    eng = terramap.Engine.create(0.1, (40, 30), layers=[{"name": "elevation", "unit": "m"}], tile=16,
                                 plugin_paths=[plugins])
    eng.add_stage("probe", "test_probe", {"increment": 0.5, "events": ["tick"]})
    for k in range(3):
        eng.push_tick(0.1 * k)
    from_yaml = terramap.Engine.from_yaml(PROBE_YAML)
    for k in range(3):
        from_yaml.push_tick(0.1 * k)
    np.testing.assert_array_equal(eng.snapshot().layer("probe"), from_yaml.snapshot().layer("probe"))
    assert eng.stage_names == ["probe"]
    with pytest.raises(terramap.ConfigError, match="increment"):
        eng.add_stage("bad", "test_probe", {"output_layer": "other", "increment": "a lot"})
    with pytest.raises(TypeError, match="'events'"):
        eng.add_stage("bad", "test_probe", {"events": [1, "tick"]})
    with pytest.raises(ValueError, match="no source"):
        eng.play()


def test_an_embedders_excavator_bucket_cuts_the_map_and_carries_the_soil():
    # A real excavator's joint states pushed from Python: blade_sweep's bucket cuts a trench
    # along the lip's path into flat ground and carries the soil (nothing deposited beside it).
    eng = terramap.Engine.create(0.05, (80, 80), layers=[{"name": "elevation", "unit": "m", "fill": 0.0}], tile=16)
    eng.add_stage("blade", "blade_sweep", {})
    c, s = np.cos(np.radians(80)), np.sin(np.radians(80))
    bucket_R = np.array([[c, 0, s], [0, 1, 0], [-s, 0, c]])  # x (toward the lip) pointing down
    lip = np.array([0.72, 0.0, 0.0])
    for k in range(40):
        links = np.tile(np.eye(4), (4, 1, 1))
        links[3, :3, :3] = bucket_R
        links[3, :3, 3] = np.array([1.0 - 0.025 * k, 0.0, -0.2]) - bucket_R @ lip
        eng.push_joint_state(links, 0.1 * k, machine_id="ex1", bucket_load_kg=10.0 * k)
    eng.finish()
    h = eng.snapshot().layer("elevation")
    assert np.nanmin(h) == pytest.approx(-0.2, abs=0.03)
    assert np.nanmax(h) <= 0.0
    counters = eng.report()["stages"][0]["counters"]
    assert counters["bucket_carried_bank_m3"] == pytest.approx(counters["bucket_cut_bank_m3"])
    assert counters["bucket_cut_bank_m3"] > 0.05
    with pytest.raises(ValueError, match="4 x 4 x 4"):
        eng.push_joint_state(np.eye(4), 5.0)

"""terramap: a parallel, layered grid-map engine for machines that move soil.

The map is a set of float32 layers (NaN = unknown) over one grid, stored in square tiles over a
ring buffer. Everything a pipeline YAML can do is reachable from here:

    import numpy as np, terramap
    eng = terramap.Engine.from_file("configs/kitti.yaml")   # or Engine.from_yaml(text)
    eng.play()                        # the pipeline's own source (sequence, sim, none)
    eng.push_cloud(pts, T, stamp)     # or your own events: N x 3/4 points, 4 x 4 poses
    snap = eng.snapshot()             # consistent copy-on-write map, valid while eng writes
    h = snap.layer("elevation")       # rows x cols float32 array in logical order (a copy)
    v = snap.tile("elevation", 0)     # read-only zero-copy view of one tile's memory
    w = snap.layer_view("elevation")  # the whole layer zero-copy, when one tile holds the map

Frames and units: the map frame is x, y horizontal and z up, metres; transforms T_a_b map
frame-b coordinates into frame a; stamps are seconds. Logical cell (i, j) has its centre at
Geometry.position_of(i, j) (grid_map's convention: i grows towards -x, j towards -y).

Subsurface soil (built with OctoMap): terramap.Strata.load(path) reads the model the
octomap_strata plugin saved (its `save_path`); s.soil_at(x, y, z) -> {"mean", "var", "source"}
with soil vectors [c (Pa), phi (rad), c_a (Pa), delta (rad), gamma (N/m^3)], s.expected_cut(x, y,
depth_m), s.surface_at(x, y), s.change_height_at(x, y).

Errors are raised as terramap.Error subclasses carrying the C++ message (file:line:col and key
for configuration errors): ConfigError, InputError, PluginError, LayerError, OutputError.
Malformed numpy input raises ValueError.

Threading: calls that run plugins release the GIL; use one Engine from one Python thread at a
time. Snapshots and their arrays may be read from any thread.
"""

from ._terramap import (  # noqa: F401
    ConfigError,
    Engine,
    Error,
    Geometry,
    InputError,
    LayerError,
    Map,
    OutputError,
    PluginError,
    add_plugin_path,
    allow_config_plugin_paths,
    fee,
    load_snapshot,
    run_pipeline,
)

try:  # built when OctoMap is (the octomap_strata plugin's model)
    from ._terramap import Strata  # noqa: F401
except ImportError:
    pass

Engine.__doc__ = """A pipeline: one map, one thread pool, plugins in YAML order.

Engine.from_file(path, threads=0) / Engine.from_yaml(text, base_dir=".", threads=0) validate the
whole pipeline first and raise ConfigError listing every problem. threads > 0 overrides the
YAML's `threads`; results are bit-identical for any thread count.
Engine.create(resolution, size, center=(0, 0), layers=[{"name", "unit", "fill"}...], tile=64,
    sparse=False, threads=2, plugin_paths=[]) builds one in code; then
add_stage(name, type, params={...}): appends a plugin stage (params: bool, int, float, str or lists),
    checked like a YAML stage (ConfigError / PluginError / LayerError).

push_cloud(points, T_map_sensor, stamp): points N x 3 (x, y, z) or N x 4 (+ intensity) in the
    sensor frame, any float dtype; T_map_sensor a rigid 4 x 4 transform (ValueError otherwise).
push_pose(T_map_base, stamp), push_blade_pose(T_map_blade, stamp, machine_id="", width_m=1.85,
    height_m=0.76), push_tick(stamp): the other events (see include/terramap/core/events.hpp).
push_joint_state(T_map_link, stamp, machine_id="", position_rad=[], bucket_load_kg=nan): an
    excavator's links (4 x 4 x 4: slew, boom, arm, bucket frames; the bucket frame as in
    docs/sim.md "Excavators") for blade_sweep's bucket and lidar_fusion's link self-filter.
play(max_events=-1): plays the pipeline's `source` (sequence folder, simulator, none) through
    the engine; returns the number of events pushed. Call again to continue.
compare_with_truth(): after play() on a source that knows the truth (the simulator), adds
    truth_elevation and elevation_error layers and returns the statistics dict (RMSE, median,
    p95, max of |error|, coverage), or None.
finish(): calls every plugin's finish() once.
snapshot() -> Map;  report() -> dict (events, per-stage counters, points dropped by reason);
stage_names -> list of stage names.
"""

Map.__doc__ = """A consistent, read-only copy of a map (copy-on-write: taking one costs pointers).

geometry, layer_names, tile_size, tile_count, start_index (the ring buffer's offset).
layer(name) -> float32 array [rows, cols] in logical order. A copy: tiles are stored in
    ring-buffer order, so no single array views a whole layer.
tile(name, t) -> read-only float32 view [rows, cols] of tile t's memory in buffer order
    (tile_rect(t) says where), or None for an unallocated tile of a sparse map (all fill). The
    view keeps the snapshot alive and never changes, whatever the engine writes afterwards.
layer_view(name) -> the whole layer as one read-only zero-copy view, when one tile holds the map
    (`tile` >= the map's size in the YAML, up to 1024) and it has not moved; ValueError otherwise.
layer_info(name) -> {name, unit, fill};  save(path): writes a .tmap file atomically.
"""

__all__ = [
    "ConfigError",
    "Engine",
    "Error",
    "Geometry",
    "InputError",
    "LayerError",
    "Map",
    "OutputError",
    "PluginError",
    "fee",
    "load_snapshot",
    "run_pipeline",
]

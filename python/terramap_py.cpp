// The `terramap._terramap` extension: the engine, its snapshots as numpy arrays, .tmap files, the
// pipeline runner and the FEE, for Python. The package `terramap` (python/terramap/__init__.py)
// re-exports it with the documentation a user reads through help(terramap).
//
// Memory: a Map wraps shared_ptr<const LayeredMap>, a copy-on-write snapshot. Tile views are
// numpy arrays over the snapshot's own tile memory whose base object keeps that snapshot alive,
// so they stay valid and unchanged however long the engine keeps writing (it copies a shared
// tile before its first write). Threading: every call that runs plugins releases the GIL; one
// Engine must not be used from two Python threads at once (the C++ Engine is single-caller).
#include <terramap/core/error.hpp>
#include <terramap/eval/sim_source.hpp>
#include <terramap/eval/truth_report.hpp>
#include <terramap/io/snapshot.hpp>
#include <terramap/pipeline/engine.hpp>
#include <terramap/pipeline/pipeline_spec.hpp>
#include <terramap/pipeline/plugin_loader.hpp>
#include <terramap/pipeline/report.hpp>
#include <terramap/pipeline/run.hpp>
#include <terramap/pipeline/source.hpp>
#include <terramap/soil/fee.hpp>
#include "sim_py.hpp"
#ifdef TERRAMAP_PY_STRATA
#include "strata.hpp"  // plugins/octomap_strata (built with OctoMap)
#endif

#include <pybind11/numpy.h>
#include <pybind11/pybind11.h>
#include <pybind11/stl.h>

#include <cmath>
#include <memory>
#include <optional>
#include <string>

namespace py = pybind11;
using namespace terramap;

namespace {

using MapPtr = std::shared_ptr<const LayeredMap>;

/// A rigid transform from a 4 x 4 matrix. \throws ValueError naming `what` when it is not one.
Eigen::Isometry3d isometryFrom(const Eigen::Matrix4d& m, const std::string& what) {
  if (!m.allFinite()) throw py::value_error(what + ": non-finite entry");
  const Eigen::Matrix3d R = m.topLeftCorner<3, 3>();
  if ((R.transpose() * R - Eigen::Matrix3d::Identity()).cwiseAbs().maxCoeff() > 1e-6 ||
      std::abs(R.determinant() - 1.0) > 1e-6 || (m.row(3) - Eigen::RowVector4d(0, 0, 0, 1)).cwiseAbs().maxCoeff() > 0)
    throw py::value_error(what + ": not a rigid transform (rotation must be orthonormal, last row 0 0 0 1)");
  Eigen::Isometry3d T = Eigen::Isometry3d::Identity();
  T.linear() = R;
  T.translation() = m.topRightCorner<3, 1>();
  return T;
}

Eigen::Isometry3d isometryFrom(const py::array_t<double, py::array::c_style | py::array::forcecast>& a,
                               const char* what) {
  if (a.ndim() != 2 || a.shape(0) != 4 || a.shape(1) != 4)
    throw py::value_error(std::string(what) + ": expected a 4x4 matrix");
  Eigen::Matrix4d m;
  for (int i = 0; i < 4; ++i)
    for (int j = 0; j < 4; ++j) m(i, j) = a.at(i, j);
  return isometryFrom(m, what);
}

py::object jsonToPython(const std::string& text) { return py::module_::import("json").attr("loads")(text); }

/// The Python face of a snapshot.
class Map {
 public:
  explicit Map(MapPtr m) : m_(std::move(m)) {}
  const LayeredMap& get() const { return *m_; }

  /// Layer in logical order (row i, column j) as a new float32 array: one copy, because the
  /// map stores tiles in ring-buffer order.
  py::array_t<float> layer(const std::string& name) const {
    const LayerId id = m_->layerId(name);
    const Size s = m_->geometry().size();
    // Column-major so readLayer writes it directly; numpy indexes it [i, j] all the same.
    py::array_t<float, py::array::f_style> out({s.x(), s.y()});
    {
      py::gil_scoped_release nogil;
      m_->readLayer(id, out.mutable_data(), s.x(), s.y());
    }
    return out;
  }

  /// Tile `t` of a layer as a read-only view of the snapshot's memory (buffer order, rows x cols
  /// of tileRect(t)); None for a tile a sparse map never allocated (every cell is the fill).
  py::object tile(const std::string& name, int t) const {
    const LayerId id = m_->layerId(name);
    if (t < 0 || t >= m_->tileCount()) throw py::index_error("tile " + std::to_string(t) + " out of range");
    const float* d = m_->tileData(id, t);
    if (!d) return py::none();
    const CellRect r = m_->tileRect(t);
    auto* keep = new MapPtr(m_);
    py::capsule owner(keep, [](void* p) { delete static_cast<MapPtr*>(p); });
    const py::ssize_t row_stride = static_cast<py::ssize_t>(sizeof(float)) * m_->tileSize();
    py::array_t<float> view({r.rows, r.cols}, {row_stride, static_cast<py::ssize_t>(sizeof(float))}, d, owner);
    py::detail::array_proxy(view.ptr())->flags &= ~py::detail::npy_api::NPY_ARRAY_WRITEABLE_;
    return std::move(view);
  }

  /// The whole layer as one zero-copy view: possible only when one tile holds the map and the
  /// ring buffer has not moved (then buffer order is logical order). \throws ValueError otherwise.
  py::object layerView(const std::string& name) const {
    const LayerId id = m_->layerId(name);
    if (m_->tileCount() != 1 || m_->startIndex().x() != 0 || m_->startIndex().y() != 0)
      throw py::value_error("layer_view('" + name + "'): the map is stored in " + std::to_string(m_->tileCount()) +
                            " tiles" + (m_->tileCount() == 1 ? " and has moved" : "") +
                            "; use layer() (a copy) or tile() views, or a map whose `tile` covers it (at most 1024 cells)");
    if (!m_->tileData(id, 0)) throw py::value_error("layer_view('" + name + "'): the layer was never written (sparse map)");
    return tile(name, 0);
  }

  py::dict tileRect(int t) const {
    if (t < 0 || t >= m_->tileCount()) throw py::index_error("tile " + std::to_string(t) + " out of range");
    const CellRect r = m_->tileRect(t);
    py::dict d;
    d["row"] = r.r0;
    d["col"] = r.c0;
    d["rows"] = r.rows;
    d["cols"] = r.cols;
    return d;
  }

  py::dict layerInfo(const std::string& name) const {
    const LayerInfo& i = m_->layerInfo(m_->layerId(name));
    py::dict d;
    d["name"] = i.name;
    d["unit"] = i.unit;
    d["fill"] = i.fill;
    return d;
  }

  void save(const std::string& path) const {
    py::gil_scoped_release nogil;
    io::saveSnapshot(*m_, path);
  }

 private:
  MapPtr m_;
};

/// A Python value as a plugin parameter (bool, int, float, str, or a list of numbers / strings).
ParamValue paramFrom(const std::string& key, const py::handle& v) {
  if (py::isinstance<py::bool_>(v)) return v.cast<bool>();
  if (py::isinstance<py::int_>(v)) return v.cast<long>();
  if (py::isinstance<py::float_>(v)) return v.cast<double>();
  if (py::isinstance<py::str>(v)) return v.cast<std::string>();
  if (py::isinstance<py::list>(v) || py::isinstance<py::tuple>(v)) {
    const py::sequence seq = v.cast<py::sequence>();
    bool strings = seq.size() > 0, numbers = true;
    for (const auto& item : seq) {
      strings = strings && py::isinstance<py::str>(item);
      numbers = numbers && (py::isinstance<py::int_>(item) || py::isinstance<py::float_>(item)) &&
                !py::isinstance<py::bool_>(item);
    }
    if (strings) return seq.cast<std::vector<std::string>>();
    if (numbers) return seq.cast<std::vector<double>>();
  }
  throw py::type_error("parameter '" + key + "': expected bool, int, float, str or a list of numbers or of strings, got " +
                       std::string(py::str(v.get_type())));
}

/// An Engine built from a pipeline (with the pipeline's source at hand for play()) or in code.
class PyEngine {
 public:
  PyEngine(PipelineSpec spec, int threads) : spec_(std::move(spec)), has_spec_(true) {
    if (threads > 0) spec_.threads = threads;
    engine_ = Engine::fromSpec(spec_, PluginRegistry::forPipeline(spec_.plugin_paths, spec_.plugin_paths_where));
  }
  PyEngine(const EngineOptions& o, std::vector<std::string> plugin_paths) : plugin_paths_(std::move(plugin_paths)) {
    engine_ = std::make_unique<Engine>(o);
  }

  void addStage(const std::string& name, const std::string& type, const py::dict& params) {
    std::map<std::string, ParamValue> values;
    for (const auto& [k, v] : params) values[k.cast<std::string>()] = paramFrom(k.cast<std::string>(), v);
    engine_->addStage(name, PluginRegistry(plugin_paths_).create(type), values);
  }

  void push(Event e) {
    py::gil_scoped_release nogil;
    engine_->push(e);
  }

  long play(long max_events) {
    if (!has_spec_) throw py::value_error("play(): this engine was built in code and has no source; push events instead");
    if (!source_) source_ = makeSource(spec_);
    long n = 0;
    py::gil_scoped_release nogil;
    Event e;
    while ((max_events < 0 || n < max_events) && source_->next(e)) {
      engine_->push(e);
      ++n;
    }
    return n;
  }

  py::object compareWithTruth() {
    if (!source_) throw py::value_error("compare_with_truth: play() the pipeline's source first");
    const TruthComparison c = eval::compareWithSourceTruth(engine_->mutableMap(), *source_);
    if (c.json.empty()) return py::none();
    return jsonToPython(c.json);
  }

  Engine& engine() { return *engine_; }

 private:
  PipelineSpec spec_;
  bool has_spec_ = false;
  std::vector<std::string> plugin_paths_;
  std::unique_ptr<Engine> engine_;
  std::unique_ptr<Source> source_;
};


/// terramap::Error and its kinds as Python exceptions carrying the C++ message.
void bindErrors(py::module_& m) {
  static py::exception<Error> error(m, "Error");
  static py::exception<ConfigError> config_error(m, "ConfigError", error.ptr());
  static py::exception<InputError> input_error(m, "InputError", error.ptr());
  static py::exception<PluginError> plugin_error(m, "PluginError", error.ptr());
  static py::exception<LayerError> layer_error(m, "LayerError", error.ptr());
  static py::exception<OutputError> output_error(m, "OutputError", error.ptr());
  // Most derived first: the first matching catch wins.
  py::register_exception_translator([](std::exception_ptr p) {
    try {
      if (p) std::rethrow_exception(p);
    } catch (const ConfigError& e) {
      config_error(e.what());
    } catch (const InputError& e) {
      input_error(e.what());
    } catch (const PluginError& e) {
      plugin_error(e.what());
    } catch (const LayerError& e) {
      layer_error(e.what());
    } catch (const OutputError& e) {
      output_error(e.what());
    } catch (const Error& e) {
      error(e.what());
    }
  });
}

/// Geometry: resolution, size, centre and the cell <-> position mapping.
void bindGeometry(py::module_& m) {
  py::class_<Geometry>(m, "Geometry", "Grid geometry: resolution (m), size (rows, cols), centre (x, y) in the map frame.")
      .def(py::init([](double resolution, std::pair<int, int> size, std::pair<double, double> center) {
             return Geometry(resolution, Size(size.first, size.second), Position(center.first, center.second));
           }),
           py::arg("resolution"), py::arg("size"), py::arg("center") = std::pair<double, double>{0.0, 0.0})
      .def_property_readonly("resolution", &Geometry::resolution)
      .def_property_readonly("size", [](const Geometry& g) { return std::make_pair(g.size().x(), g.size().y()); })
      .def_property_readonly("center", [](const Geometry& g) { return std::make_pair(g.center().x(), g.center().y()); })
      .def(
          "position_of", [](const Geometry& g, int i, int j) {
            const Position p = g.positionOf(Index(i, j));
            return std::make_pair(p.x(), p.y());
          },
          py::arg("i"), py::arg("j"), "Centre (x, y) of logical cell (i, j), metres.")
      .def(
          "index_at",
          [](const Geometry& g, double x, double y) -> std::optional<std::pair<int, int>> {
            const auto idx = g.indexAt(Position(x, y));
            if (!idx) return std::nullopt;
            return std::make_pair(idx->x(), idx->y());
          },
          py::arg("x"), py::arg("y"), "Logical cell (i, j) holding (x, y), or None outside the map.");
}

/// Map (a snapshot) with its layers as numpy arrays, and load_snapshot.
void bindMap(py::module_& m) {
  py::class_<Map>(m, "Map",
                  "A consistent copy-on-write snapshot of an engine's map (or a map loaded from .tmap).")
      .def_property_readonly("geometry", [](const Map& s) { return s.get().geometry(); })
      .def_property_readonly("layer_names", [](const Map& s) { return s.get().layerNames(); })
      .def_property_readonly("tile_size", [](const Map& s) { return s.get().tileSize(); })
      .def_property_readonly("tile_count", [](const Map& s) { return s.get().tileCount(); })
      .def_property_readonly("start_index",
                             [](const Map& s) { return std::make_pair(s.get().startIndex().x(), s.get().startIndex().y()); })
      .def("layer", &Map::layer, py::arg("name"))
      .def("tile", &Map::tile, py::arg("name"), py::arg("t"))
      .def("layer_view", &Map::layerView, py::arg("name"))
      .def("tile_rect", &Map::tileRect, py::arg("t"))
      .def("layer_info", &Map::layerInfo, py::arg("name"))
      .def("save", &Map::save, py::arg("path"));

  m.def(
      "load_snapshot",
      [](const std::string& path) {
        std::shared_ptr<const LayeredMap> p;
        {
          py::gil_scoped_release nogil;
          p = std::make_shared<const LayeredMap>(io::loadSnapshot(path));
        }
        return Map(std::move(p));
      },
      py::arg("path"));
}

/// Engine.push_*: the events, from numpy arrays and numbers.
void bindEvents(py::class_<PyEngine>& engine) {
  engine
      .def(
          "push_cloud",
          [](PyEngine& e, const py::array_t<float, py::array::c_style | py::array::forcecast>& points,
             const py::array_t<double, py::array::c_style | py::array::forcecast>& T_map_sensor, double stamp) {
            if (points.ndim() != 2 || (points.shape(1) != 3 && points.shape(1) != 4))
              throw py::value_error("push_cloud: points must be an N x 3 (x, y, z) or N x 4 (x, y, z, intensity) array");
            PointCloud c;
            c.stamp = stamp;
            c.T_map_sensor = isometryFrom(T_map_sensor, "push_cloud: T_map_sensor");
            const auto n = points.shape(0), k = points.shape(1);
            c.points.resize(static_cast<std::size_t>(n));
            const float* p = points.data();
            for (py::ssize_t i = 0; i < n; ++i) {
              PointXYZI& q = c.points[static_cast<std::size_t>(i)];
              q.x = p[i * k];
              q.y = p[i * k + 1];
              q.z = p[i * k + 2];
              q.intensity = k == 4 ? p[i * k + 3] : std::numeric_limits<float>::quiet_NaN();
            }
            e.push(std::move(c));
          },
          py::arg("points"), py::arg("T_map_sensor"), py::arg("stamp"))
      .def(
          "push_pose",
          [](PyEngine& e, const py::array_t<double, py::array::c_style | py::array::forcecast>& T, double stamp) {
            Pose p;
            p.stamp = stamp;
            p.T_map_base = isometryFrom(T, "push_pose: T_map_base");
            e.push(p);
          },
          py::arg("T_map_base"), py::arg("stamp"))
      .def(
          "push_blade_pose",
          [](PyEngine& e, const py::array_t<double, py::array::c_style | py::array::forcecast>& T, double stamp,
             const std::string& machine_id, double width_m, double height_m) {
            BladePose b;
            b.stamp = stamp;
            b.machine_id = machine_id;
            b.T_map_blade = isometryFrom(T, "push_blade_pose: T_map_blade");
            b.geometry.width_m = width_m;
            b.geometry.height_m = height_m;
            e.push(b);
          },
          py::arg("T_map_blade"), py::arg("stamp"), py::arg("machine_id") = "", py::arg("width_m") = 1.85,
          py::arg("height_m") = 0.76)
      .def(
          "push_joint_state",
          [](PyEngine& e, const py::array_t<double, py::array::c_style | py::array::forcecast>& T_links, double stamp,
             const std::string& machine_id, const std::vector<double>& position_rad, double bucket_load_kg) {
            // An excavator's links (slew, boom, arm, bucket) as a 4 x 4 x 4 array: what
            // blade_sweep's bucket and lidar_fusion's link self-filter need.
            if (T_links.ndim() != 3 || T_links.shape(0) != 4 || T_links.shape(1) != 4 || T_links.shape(2) != 4)
              throw py::value_error("push_joint_state: T_map_link: expected 4 x 4 x 4 (slew, boom, arm, bucket frames)");
            if (!position_rad.empty() && position_rad.size() != 4)
              throw py::value_error("push_joint_state: position_rad: expected 4 angles (slew, boom, arm, bucket) or none");
            JointState j;
            j.stamp = stamp;
            j.machine_id = machine_id;
            const char* names[4] = {"slew", "boom", "arm", "bucket"};
            for (int k = 0; k < 4; ++k) {
              Eigen::Matrix4d T;
              for (int r = 0; r < 4; ++r)
                for (int c = 0; c < 4; ++c) T(r, c) = T_links.at(k, r, c);
              j.T_map_link[static_cast<std::size_t>(k)] =
                  isometryFrom(T, "push_joint_state: T_map_link[" + std::to_string(k) + "] (" + names[k] + ")");
            }
            j.T_map_bucket = j.T_map_link[3];
            for (std::size_t k = 0; k < position_rad.size(); ++k) j.position_rad[k] = position_rad[k];
            j.bucket_load_kg = bucket_load_kg;
            e.push(j);
          },
          py::arg("T_map_link"), py::arg("stamp"), py::arg("machine_id") = "", py::arg("position_rad") = std::vector<double>{},
          py::arg("bucket_load_kg") = std::numeric_limits<double>::quiet_NaN())
      .def(
          "push_tick", [](PyEngine& e, double stamp) { e.push(Tick{stamp}); }, py::arg("stamp"));
}

/// Engine: pipelines from files, text or code; events from numpy; play, snapshots, report.
void bindEngine(py::module_& m) {
  py::class_<PyEngine> engine(m, "Engine");
  engine
      .def_static(
          "from_file", [](const std::string& path, int threads) { return new PyEngine(parsePipelineFile(path), threads); },
          py::arg("path"), py::arg("threads") = 0, py::return_value_policy::take_ownership)
      .def_static(
          "from_yaml",
          [](const std::string& text, const std::string& base_dir, int threads) {
            return new PyEngine(parsePipelineString(text, "<python>", base_dir), threads);
          },
          py::arg("text"), py::arg("base_dir") = ".", py::arg("threads") = 0, py::return_value_policy::take_ownership)
      .def_static(
          "create",
          [](double resolution, std::pair<int, int> size, std::pair<double, double> center, py::list layers,
             int tile, bool sparse, int threads, std::vector<std::string> plugin_paths) {
            EngineOptions o;
            o.geometry = Geometry(resolution, Size(size.first, size.second), Position(center.first, center.second));
            o.map.tile_size = tile;
            o.map.sparse = sparse;
            o.threads = threads;
            for (const auto& l : layers) {
              const py::dict d = l.cast<py::dict>();
              LayerDecl decl;
              decl.name = d["name"].cast<std::string>();
              decl.unit = d.contains("unit") ? d["unit"].cast<std::string>() : "";
              if (d.contains("fill")) decl.fill = d["fill"].cast<float>();
              o.layers.push_back(decl);
            }
            return new PyEngine(o, std::move(plugin_paths));
          },
          py::arg("resolution"), py::arg("size"), py::arg("center") = std::pair<double, double>{0.0, 0.0},
          py::arg("layers") = py::list(), py::arg("tile") = 64, py::arg("sparse") = false, py::arg("threads") = 2,
          py::arg("plugin_paths") = std::vector<std::string>{}, py::return_value_policy::take_ownership)
      .def("add_stage", &PyEngine::addStage, py::arg("name"), py::arg("type"), py::arg("params") = py::dict());
  bindEvents(engine);
  engine
      .def("play", &PyEngine::play, py::arg("max_events") = -1)
      .def(
          "finish",
          [](PyEngine& e) {
            py::gil_scoped_release nogil;
            e.engine().finish();
          })
      .def("snapshot", [](PyEngine& e) { return Map(e.engine().snapshot()); })
      .def_property_readonly("stage_names", [](PyEngine& e) { return e.engine().stageNames(); })
      .def("report", [](PyEngine& e) { return jsonToPython(reportToJson(e.engine().report())); })
      .def("compare_with_truth", &PyEngine::compareWithTruth);
}

/// run_pipeline (the whole runner) and fee (the FEE calculator).
void bindFunctions(py::module_& m) {
  m.def(
      "allow_config_plugin_paths", [](bool allow) { PluginRegistry::allowConfigPluginPaths(allow); },
      py::arg("allow") = true,
      "Let pipeline files' plugin_paths name folders whose libraries are loaded (their code runs): only for files "
      "you trust (docs/reliability.md, \"What a config file can make terramap do\"). Off by default.");
  m.def(
      "add_plugin_path", [](const std::string& dir) { PluginRegistry::addTrustedPaths({dir}); }, py::arg("dir"),
      "Search this folder for plugins from now on (as the CLI's --plugin-path).");
  m.def(
      "run_pipeline",
      [](const std::string& path, const std::string& out, int threads) {
        RunOptions o;
        o.out_dir = out;
        o.threads = threads;
        o.compare_truth = eval::compareWithSourceTruth;
        o.truth_stats = eval::truthStatsJson;
        const PipelineSpec spec = parsePipelineFile(path);
        RunResult r;
        {
          py::gil_scoped_release nogil;
          r = runPipeline(spec, o);
        }
        py::dict d;
        d["out_dir"] = r.out_dir;
        d["files"] = r.files;
        d["report"] = jsonToPython(reportToJson(r.report));
        return d;
      },
      py::arg("path"), py::arg("out") = "", py::arg("threads") = 0);

  m.def(
      "fee",
      [](double c_pa, double phi_rad, double gamma_n_m3, double ca_pa, double delta_rad, double alpha_rad,
         double rho_rad, double d_m, double w_m, double q_n, std::optional<double> beta_rad, const std::string& beta) {
        const fee::Soil s{c_pa, phi_rad, gamma_n_m3, ca_pa, delta_rad};
        fee::Geometry g;
        g.alpha_rad = alpha_rad;
        g.rho_rad = rho_rad;
        g.d_m = d_m;
        g.w_m = w_m;
        g.q_n = q_n;
        if (!beta_rad && beta != "min" && beta != "nominal")
          throw py::value_error("fee: beta must be 'min' (beta* minimising N_gamma) or 'nominal' (pi/4 - phi/2)");
        const fee::Result r = beta_rad          ? fee::evaluate(s, g, *beta_rad)
                              : beta == "min" ? fee::evaluateAtBetaMin(s, g)
                                              : fee::evaluateAtBetaNominal(s, g);
        py::dict d;
        d["beta_rad"] = r.beta_rad;
        d["f_N"] = r.f_N;
        d["F_N"] = std::make_pair(r.F_N.x(), r.F_N.y());
        d["F_total_N"] = std::make_pair(r.F_total_N.x(), r.F_total_N.y());
        d["N_gamma"] = r.n.N_gamma;
        d["N_c"] = r.n.N_c;
        d["N_Q"] = r.n.N_Q;
        d["N_ca"] = r.n.N_ca;
        d["valid"] = r.valid();
        d["validity"] = fee::validityName(r.validity);
        return d;
      },
      py::arg("c_pa"), py::arg("phi_rad"), py::arg("gamma_n_m3"), py::arg("ca_pa"), py::arg("delta_rad"),
      py::arg("alpha_rad"), py::arg("rho_rad"), py::arg("d_m"), py::arg("w_m"), py::arg("q_n") = 0.0,
      py::arg("beta_rad") = py::none(), py::arg("beta") = "min",
      "The fundamental equation of earthmoving for one soil and blade (SI units, radians), as\n"
      "`terramap fee` computes it: at beta_rad if given, else at beta* ('min') or Rankine's\n"
      "pi/4 - phi/2 ('nominal'). Returns beta_rad, f_N, F_N and F_total_N (x along travel, z up, N),\n"
      "the N-factors, valid and validity (the rule that failed).");
}

}  // namespace

#ifdef TERRAMAP_PY_STRATA
/// Strata: a model octomap_strata saved (`save_path`), read back for queries.
void bindStrata(py::module_& m) {
  using strata::Strata;
  auto belief = [](const strata::SoilBelief& b) {
    py::dict d;
    py::array_t<double> mean(soil::kSoilParamCount), var(soil::kSoilParamCount);
    for (int q = 0; q < soil::kSoilParamCount; ++q) {
      mean.mutable_at(q) = b.mean[static_cast<std::size_t>(q)];
      var.mutable_at(q) = b.var[static_cast<std::size_t>(q)];
    }
    d["mean"] = mean;
    d["var"] = var;
    d["source"] = strata::soilSourceName(b.source);
    return d;
  };
  py::class_<Strata>(m, "Strata",
                     "Subsurface soil memory written by the octomap_strata plugin (save_path). Soil vectors in the "
                     "order [c (Pa), phi (rad), c_a (Pa), delta (rad), gamma (N/m^3)]; map frame, metres.")
      .def_static("load", [](const std::string& path) { return Strata::load(path); }, py::arg("path"), "Reads a file written by octomap_strata's save_path.")
      .def("soil_at",
           [belief](const Strata& s, double x, double y, double z) { return belief(s.soilAt(x, y, z)); },
           py::arg("x"), py::arg("y"), py::arg("z"),
           "Belief about the soil at (x, y, z): {'mean', 'var', 'source'}; source is 'removed' (a cut's estimate), "
           "'predicted', 'inherited' (below a cut, variance inflated by depth), 'prior', 'air' or 'outside'.")
      .def("expected_cut",
           [belief](const Strata& s, double x, double y, double depth_m) {
             return belief(s.expectedCut(x, y, std::numeric_limits<double>::quiet_NaN(), depth_m));
           },
           py::arg("x"), py::arg("y"), py::arg("depth_m") = 0.2, "The soil the next cut of depth_m would remove.")
      .def("surface_at", &Strata::surfaceAt, py::arg("x"), py::arg("y"), "Bank surface of the column (NaN: never cut).")
      .def("initial_surface_at", &Strata::initialSurfaceAt, py::arg("x"), py::arg("y"))
      .def("change_height_at",
           [](const Strata& s, double x, double y, int min_voxels, double min_gain, double radius_m) {
             return s.changeHeightAt(x, y, min_voxels, min_gain, radius_m);
           },
           py::arg("x"), py::arg("y"), py::arg("min_voxels") = 1,
           py::arg("min_gain") = 0.5, py::arg("radius_m") = 0.0, "Height of the strongest change in the removed soil.")
      .def_property_readonly("resolution", [](const Strata& s) { return s.config().resolution_m; })
      .def_property_readonly("columns", &Strata::columns)
      .def_property_readonly("nodes", &Strata::nodes)
      .def_property_readonly("memory_bytes", &Strata::memoryBytes);
}
#endif

PYBIND11_MODULE(_terramap, m) {
  m.doc() = "terramap's C++ engine (see the terramap package for the documentation)";
  sim::registerSimSource();
  bindErrors(m);
  bindGeometry(m);
  bindMap(m);
  bindEngine(m);
  bindFunctions(m);
  bindSim(m);
#ifdef TERRAMAP_PY_STRATA
  bindStrata(m);
#endif
}

// `terramap._terramap.sim`: the simulator's environment API (sim/env.hpp) for Python, in the
// shape Gymnasium users expect: reset(seed=None, options=None) -> (obs, info) and
// step(action) -> (obs, rewards, terminated, truncated, info). Observations and batched results
// are numpy arrays; a LiDAR cloud's points are an (n, 4) float32 array over the cloud's own
// memory (no copy), kept alive by the array. Every step and reset releases the GIL.
#include "sim_py.hpp"

#include <terramap/sim/env.hpp>

#include <pybind11/numpy.h>
#include <pybind11/stl.h>

#include <cmath>
#include <memory>
#include <string>

namespace py = pybind11;
using namespace terramap;
using namespace terramap::sim;

namespace {

using DArray = py::array_t<double, py::array::c_style | py::array::forcecast>;

py::array_t<double> toArray(const std::vector<double>& v) {
  py::array_t<double> a(static_cast<py::ssize_t>(v.size()));
  std::copy(v.begin(), v.end(), a.mutable_data());
  return a;
}

py::array_t<double> matrixOf(const Eigen::Isometry3d& T) {
  py::array_t<double> a({4, 4});
  auto m = a.mutable_unchecked<2>();
  for (int i = 0; i < 4; ++i)
    for (int j = 0; j < 4; ++j) m(i, j) = T.matrix()(i, j);
  return a;
}

/// A cloud's points as an (n, 4) float32 array (x, y, z, intensity; sensor frame) that owns the
/// moved vector: no copy.
py::array cloudPoints(std::vector<PointXYZI>&& pts) {
  auto* owned = new std::vector<PointXYZI>(std::move(pts));
  py::capsule base(owned, [](void* p) { delete static_cast<std::vector<PointXYZI>*>(p); });
  static_assert(sizeof(PointXYZI) == 4 * sizeof(float), "PointXYZI must be four packed floats");
  return py::array_t<float>({static_cast<py::ssize_t>(owned->size()), static_cast<py::ssize_t>(4)},
                            {static_cast<py::ssize_t>(sizeof(PointXYZI)), static_cast<py::ssize_t>(sizeof(float))},
                            reinterpret_cast<const float*>(owned->data()), base);
}

py::dict truthDict(const MachineTruth& t) {
  py::dict d;
  d["T_map_base"] = matrixOf(t.T_map_base);
  d["T_map_blade"] = matrixOf(t.T_map_blade);
  d["force_map_N"] = py::make_tuple(t.force_map_N.x(), t.force_map_N.y(), t.force_map_N.z());
  d["cut_bank_m3"] = t.cut_bank_m3;
  d["stalled"] = t.stalled;
  d["cylinder_length_m"] = t.cylinder_length_m;
  if (t.has_arm) {
    d["arm_q"] = t.arm_q;
    d["arm_qd"] = t.arm_qd;
    d["T_map_bucket"] = matrixOf(t.T_map_bucket);
    d["bucket_load_kg"] = t.bucket_load_kg;
  }
  return d;
}

py::dict termsDict(const std::vector<std::string>& names, const std::vector<double>& v) {
  py::dict d;
  for (std::size_t i = 0; i < names.size(); ++i) d[py::str(names[i])] = v[i];
  return d;
}

/// Per agent: what the observation vector does not hold (clouds, IMU samples, truth).
py::dict agentExtras(AgentObservation& o) {
  py::dict d;
  py::list clouds;
  for (PointCloud& pc : o.clouds) {
    py::dict c;
    c["frame"] = pc.frame;
    c["stamp"] = pc.stamp;
    c["T_map_sensor"] = matrixOf(pc.T_map_sensor);
    c["points"] = cloudPoints(std::move(pc.points));
    clouds.append(c);
  }
  d["clouds"] = clouds;
  py::list imu;
  for (const ImuSample& s : o.imu)
    imu.append(py::dict(py::arg("frame") = s.frame, py::arg("stamp") = s.stamp,
                        py::arg("accel_mps2") = py::make_tuple(s.accel_mps2.x(), s.accel_mps2.y(), s.accel_mps2.z()),
                        py::arg("gyro_radps") = py::make_tuple(s.gyro_radps.x(), s.gyro_radps.y(), s.gyro_radps.z())));
  d["imu"] = imu;
  if (o.truth) d["truth"] = truthDict(*o.truth);
  return d;
}

/// The Gymnasium-shaped results of one environment: with one agent the bare array and terms,
/// with several a dict keyed by agent id.
struct Converted {
  py::object obs, rewards;
  py::dict info;
};

Converted convert(const Env& env, StepResult& r) {
  Converted c;
  const bool single = env.agentCount() == 1;
  py::dict obs, rew, agents;
  for (std::size_t a = 0; a < env.agentCount(); ++a) {
    const py::str id(env.agentId(a));
    obs[id] = toArray(r.observation[a].vector);
    rew[id] = termsDict(RewardTerms::names(), r.rewards[a].toVector());
    agents[id] = agentExtras(r.observation[a]);
  }
  const py::str id0(env.agentId(0));
  c.obs = single ? py::object(obs[id0]) : py::object(obs);
  c.rewards = single ? py::object(rew[id0]) : py::object(rew);
  c.info["t"] = r.info.t;
  c.info["episode_step"] = r.info.episode_step;
  c.info["seed"] = r.info.seed;
  c.info["rebuilt_terrain"] = r.info.rebuilt_terrain;
  c.info["task"] = termsDict(TaskTerms::names(), r.task.toVector());
  if (single) {
    for (auto kv : py::dict(agents[id0])) c.info[kv.first] = kv.second;
  } else {
    c.info["agents"] = agents;
  }
  return c;
}

EnvOptions optionsFrom(int frame_skip, double time_limit_s, bool clouds, bool truth, const py::object& target, int threads) {
  EnvOptions o;
  o.frame_skip = frame_skip;
  o.time_limit_s = time_limit_s;
  o.clouds = clouds;
  o.truth = truth;
  o.threads = threads;
  if (!target.is_none()) {
    const py::dict t = target.cast<py::dict>();
    static const char* keys[] = {"x0", "y0", "x1", "y1", "depth_m", "height_m", "tolerance_m"};
    for (auto kv : t) {
      const std::string k = kv.first.cast<std::string>();
      if (std::find_if(std::begin(keys), std::end(keys), [&](const char* s) { return k == s; }) == std::end(keys))
        throw py::value_error("target: unknown key '" + k + "' (x0, y0, x1, y1, depth_m, height_m, tolerance_m)");
    }
    auto get = [&](const char* k, double def) { return t.contains(k) ? t[k].cast<double>() : def; };
    const double nan = std::nan("");
    o.target = {get("x0", 0), get("y0", 0), get("x1", 0), get("y1", 0), get("depth_m", nan), get("height_m", nan),
                get("tolerance_m", nan)};
    if (!o.target.enabled()) throw py::value_error("target: needs x1 > x0 and y1 > y0 (a rectangle of the map, m)");
  }
  return o;
}

/// Overrides as the C++ API takes them: a YAML string as is, a dict through JSON (which is YAML).
std::string overridesText(const py::object& options) {
  if (options.is_none()) return "";
  const py::dict d = options.cast<py::dict>();
  for (auto kv : d)
    if (kv.first.cast<std::string>() != "overrides")
      throw py::value_error("reset options: unknown key '" + kv.first.cast<std::string>() + "' (overrides)");
  if (!d.contains("overrides") || d["overrides"].is_none()) return "";
  const py::object o = d["overrides"];
  if (py::isinstance<py::str>(o)) return o.cast<std::string>();
  return py::module_::import("json").attr("dumps")(o).cast<std::string>();
}

/// One environment's levers, flat in agent order, from an array (one agent) or a dict by id.
std::vector<double> flatAction(const Env& env, const py::object& action) {
  std::vector<double> flat;
  auto take = [&](std::size_t a, const py::object& o) {
    const DArray arr = DArray::ensure(o);
    if (!arr || arr.ndim() != 1 || static_cast<std::size_t>(arr.shape(0)) != env.actionSize(a))
      throw py::value_error("agent " + env.agentId(a) + ": expected an array of " + std::to_string(env.actionSize(a)) +
                            " levers (" + [&] {
                              std::string s;
                              for (const auto& n : env.actionNames(a)) s += (s.empty() ? "" : ", ") + n;
                              return s;
                            }() + ")");
    flat.insert(flat.end(), arr.data(), arr.data() + arr.shape(0));
  };
  if (py::isinstance<py::dict>(action)) {
    const py::dict d = action.cast<py::dict>();
    for (std::size_t a = 0; a < env.agentCount(); ++a) {
      if (!d.contains(env.agentId(a))) throw py::value_error("action: no levers for agent " + env.agentId(a));
      take(a, d[py::str(env.agentId(a))]);
    }
    if (d.size() != env.agentCount()) throw py::value_error("action: levers for an agent that is not one");
  } else {
    if (env.agentCount() != 1) throw py::value_error("action: several agents: pass a dict {agent id: levers}");
    take(0, action);
  }
  return flat;
}

/// The Python Env: the C++ one and the agents' names.
struct PyEnv {
  std::unique_ptr<Env> env;
};

struct PyVectorEnv {
  std::unique_ptr<VectorEnv> venv;
};

py::object batched(const VectorEnv& v, const std::vector<std::vector<double>>& per_agent_flat,
                   const std::function<std::size_t(std::size_t)>& width) {
  py::dict d;
  for (std::size_t a = 0; a < v.agentCount(); ++a) {
    py::array_t<double> arr({static_cast<py::ssize_t>(v.size()), static_cast<py::ssize_t>(width(a))});
    std::copy(per_agent_flat[a].begin(), per_agent_flat[a].end(), arr.mutable_data());
    d[py::str(v.env(0).agentId(a))] = arr;
  }
  if (v.agentCount() == 1) return d[py::str(v.env(0).agentId(0))];
  return d;
}

py::object vectorObs(const VectorEnv& v) {
  std::vector<std::vector<double>> o;
  for (std::size_t a = 0; a < v.agentCount(); ++a) o.push_back(v.observations(a));
  return batched(v, o, [&](std::size_t a) { return v.env(0).observationSize(a); });
}

/// Terms as {name: array[N]} from a row-major [N][names] array.
py::dict columns(const std::vector<std::string>& names, const std::vector<double>& rows, int n) {
  py::dict d;
  for (std::size_t c = 0; c < names.size(); ++c) {
    py::array_t<double> col(n);
    for (int k = 0; k < n; ++k) col.mutable_data()[k] = rows[static_cast<std::size_t>(k) * names.size() + c];
    d[py::str(names[c])] = col;
  }
  return d;
}

py::dict vectorInfo(VectorEnv& v, bool with_final) {
  py::dict info;
  info["t"] = toArray(v.times());
  info["task"] = columns(TaskTerms::names(), v.task(), v.size());
  if (with_final) {
    py::list fin;
    for (int k = 0; k < v.size(); ++k) {
      if (v.terminated()[k] || v.truncated()[k]) {
        StepResult r = v.finalObservation(k);
        Converted c = convert(v.env(k), r);
        fin.append(py::make_tuple(c.obs, c.info));
      } else {
        fin.append(py::none());
      }
    }
    info["final_observation"] = fin;
  }
  return info;
}

}  // namespace

void bindSim(py::module_& parent) {
  py::module_ m = parent.def_submodule("sim", "The simulator as an environment (terramap.sim)");

  py::class_<PyEnv>(m, "Env")
      .def(py::init([](const std::string& scenario_path, int frame_skip, double time_limit_s, bool clouds, bool truth,
                       const py::object& target, int threads) {
             auto e = std::make_unique<PyEnv>();
             e->env = std::make_unique<Env>(loadScenario(scenario_path),
                                            optionsFrom(frame_skip, time_limit_s, clouds, truth, target, threads));
             return e;
           }),
           py::arg("scenario"), py::arg("frame_skip") = 1, py::arg("time_limit_s") = std::nan(""),
           py::arg("clouds") = false, py::arg("truth") = false, py::arg("target") = py::none(), py::arg("threads") = 1)
      .def_static(
          "from_yaml",
          [](const std::string& text, const std::string& base_dir, int frame_skip, double time_limit_s, bool clouds,
             bool truth, const py::object& target, int threads) {
            auto e = std::make_unique<PyEnv>();
            e->env = std::make_unique<Env>(parseScenario(text, "<yaml>", base_dir),
                                           optionsFrom(frame_skip, time_limit_s, clouds, truth, target, threads));
            return e;
          },
          py::arg("text"), py::arg("base_dir") = ".", py::arg("frame_skip") = 1, py::arg("time_limit_s") = std::nan(""),
          py::arg("clouds") = false, py::arg("truth") = false, py::arg("target") = py::none(), py::arg("threads") = 1)
      .def(
          "reset",
          [](PyEnv& self, std::optional<std::uint64_t> seed, const py::object& options) {
            const std::string over = overridesText(options);
            StepResult r;
            {
              py::gil_scoped_release nogil;
              r = self.env->reset(seed, over);
            }
            Converted c = convert(*self.env, r);
            return py::make_tuple(c.obs, c.info);
          },
          py::arg("seed") = py::none(), py::arg("options") = py::none())
      .def("step",
           [](PyEnv& self, const py::object& action) {
             const std::vector<double> a = flatAction(*self.env, action);
             StepResult r;
             {
               py::gil_scoped_release nogil;
               r = self.env->step(a.data(), a.size());
             }
             Converted c = convert(*self.env, r);
             return py::make_tuple(c.obs, c.rewards, r.terminated, r.truncated, c.info);
           })
      .def_property_readonly("agents",
                             [](const PyEnv& self) {
                               std::vector<std::string> ids;
                               for (std::size_t a = 0; a < self.env->agentCount(); ++a) ids.push_back(self.env->agentId(a));
                               return ids;
                             })
      .def("action_names", [](const PyEnv& self, std::size_t a) { return self.env->actionNames(a); }, py::arg("agent") = 0)
      .def("observation_names", [](const PyEnv& self, std::size_t a) { return self.env->observationNames(a); },
           py::arg("agent") = 0)
      .def_property_readonly("time", [](const PyEnv& self) { return self.env->simulator().time(); })
      .def_property_readonly("observation_hz", [](const PyEnv& self) { return self.env->scenario().observation_hz; })
      .def("terrain_heights",
           [](const PyEnv& self) {
             const TruthTerrain& t = self.env->simulator().truth();
             py::array_t<double> h({static_cast<py::ssize_t>(t.ny()), static_cast<py::ssize_t>(t.nx())});
             std::copy(t.heightData().begin(), t.heightData().end(), h.mutable_data());
             return py::make_tuple(h, t.originX(), t.originY(), t.resolution());
           })
      .def_property_readonly_static("reward_terms", [](const py::object&) { return RewardTerms::names(); })
      .def_property_readonly_static("task_terms", [](const py::object&) { return TaskTerms::names(); });

  py::class_<PyVectorEnv>(m, "VectorEnv")
      .def(py::init([](const std::string& scenario_path, int num_envs, int threads, int frame_skip, double time_limit_s,
                       bool clouds, bool truth, const py::object& target) {
             VectorEnvOptions o;
             o.env = optionsFrom(frame_skip, time_limit_s, clouds, truth, target, 1);
             o.threads = threads;
             const Scenario sc = loadScenario(scenario_path);
             auto v = std::make_unique<PyVectorEnv>();
             py::gil_scoped_release nogil;
             v->venv = std::make_unique<VectorEnv>(sc, num_envs, o);
             return v;
           }),
           py::arg("scenario"), py::arg("num_envs"), py::arg("threads") = 1, py::arg("frame_skip") = 1,
           py::arg("time_limit_s") = std::nan(""), py::arg("clouds") = false, py::arg("truth") = false,
           py::arg("target") = py::none())
      .def(
          "reset",
          [](PyVectorEnv& self, std::optional<std::uint64_t> seed) {
            {
              py::gil_scoped_release nogil;
              self.venv->reset(seed);
            }
            return py::make_tuple(vectorObs(*self.venv), vectorInfo(*self.venv, false));
          },
          py::arg("seed") = py::none())
      .def("step",
           [](PyVectorEnv& self, const py::object& actions) {
             VectorEnv& v = *self.venv;
             const DArray arr = DArray::ensure(actions);
             if (!arr || arr.ndim() != 2 || arr.shape(0) != v.size() ||
                 static_cast<std::size_t>(arr.shape(1)) != v.actionWidth())
               throw py::value_error("actions: expected an array of shape (" + std::to_string(v.size()) + ", " +
                                     std::to_string(v.actionWidth()) + "): one row of levers per environment, agents in order");
             {
               py::gil_scoped_release nogil;
               v.step(arr.data(), static_cast<std::size_t>(arr.size()));
             }
             std::vector<std::vector<double>> rew;
             py::dict rewards;
             for (std::size_t a = 0; a < v.agentCount(); ++a)
               rewards[py::str(v.env(0).agentId(a))] = columns(RewardTerms::names(), v.rewards(a), v.size());
             py::array_t<bool> term(v.size()), trunc(v.size());
             for (int k = 0; k < v.size(); ++k) {
               term.mutable_data()[k] = v.terminated()[k] != 0;
               trunc.mutable_data()[k] = v.truncated()[k] != 0;
             }
             py::object rw = v.agentCount() == 1 ? py::object(rewards[py::str(v.env(0).agentId(0))]) : py::object(rewards);
             return py::make_tuple(vectorObs(v), rw, term, trunc, vectorInfo(v, true));
           })
      .def_property_readonly("num_envs", [](const PyVectorEnv& self) { return self.venv->size(); })
      .def_property_readonly("action_width", [](const PyVectorEnv& self) { return self.venv->actionWidth(); })
      .def("observation_names", [](const PyVectorEnv& self, std::size_t a) { return self.venv->env(0).observationNames(a); },
           py::arg("agent") = 0)
      .def("action_names", [](const PyVectorEnv& self, std::size_t a) { return self.venv->env(0).actionNames(a); },
           py::arg("agent") = 0);
}

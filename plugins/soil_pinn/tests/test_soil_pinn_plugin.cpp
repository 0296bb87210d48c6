// The soil_pinn plugin in an Engine after the real blade_sweep, on a flat known map and a
// synthetic 60 Hz drive (BladePose then Observation at every stamp, so every sweep waits for
// its last observation): it publishes, for every sweep that gives a sample, the estimate of
// exactly the sample the dataset builds (soil::buildSample, dataset-style pending sweeps) fed to
// the same SoilEstimator; a sweep that cuts nothing publishes nothing and counts fee_invalid; a
// missing or foreign model file is a ConfigError naming the file; the same records whichever of
// a stamp's two events comes first; records bit-identical at 1 and 2 engine threads.
#include "estimator.hpp"
#include "soil_pinn_plugin.hpp"

#include <terramap/core/error.hpp>
#include <terramap/pipeline/engine.hpp>
#include <terramap/plugin/records/soil_estimate_record.hpp>
#include <terramap/plugin/records/sweep_record.hpp>
#include <terramap/soil/fee.hpp>
#include <terramap/soil/pinn_sample.hpp>

#include <ATen/Parallel.h>
#include <torch/csrc/autograd/grad_mode.h>
#include <gtest/gtest.h>
#include <unistd.h>

#include <cmath>
#include <cstdio>
#include <cstring>
#include <fstream>
#include <map>
#include <memory>
#include <string>
#include <vector>

using namespace terramap;

namespace {

constexpr int kT = 10, kP = 4;
constexpr double kDt = 1.0 / 60.0;

std::string tempPath(const std::string& name) {
  return ::testing::TempDir() + "/soil_pinn_plugin_" + std::to_string(::getpid()) + "_" + name;
}

// Removes the model file when the test binary ends.
struct RemoveFiles : ::testing::Environment {
  std::vector<std::string> paths;
  void TearDown() override {
    for (const auto& p : paths) std::remove(p.c_str());
  }
};
RemoveFiles* const kRemoveFiles =
    static_cast<RemoveFiles*>(::testing::AddGlobalTestEnvironment(new RemoveFiles));

// A tiny untrained ensemble of three members, saved once per test binary.
const std::string& modelPath() {
  static const std::string path = [] {
    std::vector<pinn::PinnNet> members;
    for (int64_t seed : {11, 12, 13}) members.emplace_back(pinn::PinnConfig{kT, kP, soil::kObsFeatures, {8}, seed});
    pinn::SoilEstimator e(std::move(members), std::vector<float>(soil::kObsFeatures, 0.0f),
                          std::vector<float>(soil::kObsFeatures, 1.0f));
    const std::string p = tempPath("model.pt");
    pinn::saveEstimator(e, p);
    kRemoveFiles->paths.push_back(p);
    return p;
  }();
  return path;
}

// The drive: machine "m" heading +x at 0.5 m/s, blade edge 1.9 m ahead of the base, face
// leaning back 0.15 rad. `depth(t)`: the edge's depth below the flat ground (z = 0), negative
// = above it. BladePose first, then the Observation of the same stamp.
struct Drive {
  double duration_s = 4.0;
  double speed = 0.5;
  std::function<double(double)> depth;
  bool observation_first = false;  ///< order of the two events of one stamp
};

std::vector<Event> driveEvents(const Drive& d) {
  std::vector<Event> ev;
  const int n = static_cast<int>(std::lround(d.duration_s / kDt));
  const double lean = 0.15;
  for (int i = 0; i <= n; ++i) {
    const double t = i * kDt;
    const double dep = d.depth(t);
    const Eigen::Vector3d edge(-1.5 + d.speed * t, 0.0, -dep);
    Eigen::Isometry3d T_blade = Eigen::Isometry3d::Identity();
    T_blade.linear() = Eigen::AngleAxisd(-lean, Eigen::Vector3d::UnitY()).toRotationMatrix();
    T_blade.translation() = edge;
    BladePose bp;
    bp.stamp = t;
    bp.machine_id = "m";
    bp.T_map_blade = T_blade;
    ev.emplace_back(bp);
    Observation o;
    o.stamp = t;
    o.machine_id = "m";
    o.T_map_base = Eigen::Translation3d(edge + Eigen::Vector3d(-1.9, 0.0, dep + 0.6)) * Eigen::Quaterniond::Identity();
    o.T_map_blade = T_blade;
    o.twist_base << d.speed, 0, 0, 0, 0, 0;
    o.twist_blade << d.speed * std::cos(lean), 0, d.speed * std::sin(lean), 0, 0, 0;
    o.cylinder_length_m = {0.5 - dep, 0.6, 0.7};
    o.track_speed_mps = {d.speed, d.speed};
    o.engine_speed_rpm = 2200;
    o.action = {d.speed, d.speed, 0.0, 0.0, 0.0};
    const double cut = std::max(0.0, dep);
    o.force_base_N = Eigen::Vector3d(-60000.0 * cut - 200.0, 0.0, 15000.0 * cut);
    ev.emplace_back(o);
    if (d.observation_first) std::swap(ev[ev.size() - 2], ev[ev.size() - 1]);
  }
  return ev;
}

Drive cuttingDrive() {
  Drive d;
  // Above the ground for 0.5 s, then down to 6 cm over 1 s, then level.
  d.depth = [](double t) { return t < 0.5 ? -0.05 : std::min(0.06, -0.05 + 0.11 * (t - 0.5)); };
  return d;
}

Drive airDrive() {
  Drive d;
  d.depth = [](double) { return -0.3; };  // 30 cm above the ground the whole time
  return d;
}

struct RunResult {
  std::vector<std::shared_ptr<const SoilEstimateRecord>> estimates;
  std::vector<std::shared_ptr<const SweepRecord>> sweeps;
  // What the dataset builds: samples of the sweeps, built after each stamp's events.
  std::vector<soil::PinnSample> samples;
  std::map<std::string, long> skipped;
  StageReport soil_report;
};

std::unique_ptr<Engine> makeEngine(int threads, const std::string& model) {
  EngineOptions o;
  o.geometry = Geometry(0.05, Size(120, 120));
  o.threads = threads;
  LayerDecl elevation;
  elevation.name = "elevation";
  elevation.unit = "m";
  o.layers = {elevation};
  auto e = std::make_unique<Engine>(o);
  e->editMap([](LayeredMap& m) {
    const Size s = m.geometry().size();
    m.fromMatrix(m.layerId("elevation"), Eigen::MatrixXf::Zero(s.x(), s.y()));
  });
  const std::string dir = TERRAMAP_PLUGIN_DIR;
  e->addStage("blade", PluginRegistry::createFromFile(dir + "/blade_sweep.so", "blade_sweep"));
  e->addStage("soil", PluginRegistry::createFromFile(dir + "/soil_pinn.so", "soil_pinn"), {{"model", model}});
  return e;
}

RunResult run(const Drive& d, int threads) {
  auto engine = makeEngine(threads, modelPath());
  RunResult r;
  long sweep_seq = 0, est_seq = 0;
  soil::ObservationHistory history(kT + 64);
  std::vector<std::shared_ptr<const SweepRecord>> pending;
  auto look = [&] {
    if (const Record* s = engine->records().latest(SweepRecord::kType); s && s->sequence != sweep_seq) {
      EXPECT_EQ(s->sequence, sweep_seq + 1);
      sweep_seq = s->sequence;
      auto rec = std::static_pointer_cast<const SweepRecord>(s->payload);
      r.sweeps.push_back(rec);
      pending.push_back(rec);
    }
    if (const Record* s = engine->records().latest(SoilEstimateRecord::kType); s && s->sequence != est_seq) {
      EXPECT_EQ(s->sequence, est_seq + 1) << "more than one estimate in one event";
      est_seq = s->sequence;
      r.estimates.push_back(std::static_pointer_cast<const SoilEstimateRecord>(s->payload));
    }
  };
  auto build = [&] {
    for (const auto& rec : pending) {
      soil::PinnSample s;
      const soil::SampleSkip why = soil::buildSample(history, *rec, kT, kP, s);
      if (why != soil::SampleSkip::None)
        ++r.skipped[soil::sampleSkipName(why)];
      else
        r.samples.push_back(std::move(s));
    }
    pending.clear();
  };
  const std::vector<Event> events = driveEvents(d);
  for (std::size_t i = 0; i < events.size(); ++i) {
    if (const auto* o = std::get_if<Observation>(&events[i])) history.push(*o);
    engine->push(events[i]);
    look();
    if (i % 2 == 1) build();  // after both events of a stamp, as the dataset does per step
  }
  engine->finish();
  look();
  build();
  r.soil_report = engine->report().stages.at(1);
  return r;
}

bool sameBits(double a, double b) { return std::memcmp(&a, &b, sizeof a) == 0; }

template <std::size_t N>
void expectSameBits(const std::array<double, N>& a, const std::array<double, N>& b, const char* what) {
  for (std::size_t k = 0; k < N; ++k) EXPECT_TRUE(sameBits(a[k], b[k])) << what << "[" << k << "]: " << a[k] << " vs " << b[k];
}

void expectSameRecord(const SoilEstimateRecord& a, const SoilEstimateRecord& b) {
  EXPECT_EQ(a.sweep_index, b.sweep_index);
  EXPECT_EQ(a.machine_id, b.machine_id);
  EXPECT_TRUE(sameBits(a.t0, b.t0) && sameBits(a.t1, b.t1) && sameBits(a.stamp, b.stamp));
  EXPECT_EQ(a.history_T, b.history_T);
  EXPECT_EQ(a.horizon_P, b.horizon_P);
  EXPECT_TRUE(a.T_map_blade1.matrix() == b.T_map_blade1.matrix());
  EXPECT_TRUE(a.t_hat == b.t_hat);
  EXPECT_TRUE(sameBits(a.alpha_rad, b.alpha_rad) && sameBits(a.rho_rad, b.rho_rad) && sameBits(a.d_m, b.d_m) &&
              sameBits(a.w_m, b.w_m));
  EXPECT_TRUE(sameBits(a.beta_rad, b.beta_rad) && sameBits(a.d_res_m, b.d_res_m) &&
              sameBits(a.beta_res_rad, b.beta_res_rad));
  expectSameBits(a.mean, b.mean, "mean");
  expectSameBits(a.var_total, b.var_total, "var_total");
  expectSameBits(a.var_aleatoric, b.var_aleatoric, "var_aleatoric");
  expectSameBits(a.var_nullspace, b.var_nullspace, "var_nullspace");
  expectSameBits(a.var_epistemic, b.var_epistemic, "var_epistemic");
  expectSameBits(a.F_r, b.F_r, "F_r");
  expectSameBits(a.F_pred, b.F_pred, "F_pred");
  expectSameBits(a.F_measured, b.F_measured, "F_measured");
  EXPECT_EQ(a.members, b.members);
  EXPECT_EQ(a.valid_members, b.valid_members);
  EXPECT_EQ(a.valid, b.valid);
  EXPECT_EQ(a.invalid_reason, b.invalid_reason);
}

}  // namespace

TEST(SoilPinnPlugin, PublishesTheEstimateOfTheDatasetSample) {
  at::set_num_threads(1);
  const RunResult r = run(cuttingDrive(), 1);
  ASSERT_GE(r.sweeps.size(), 5u);
  ASSERT_GE(r.samples.size(), 3u) << "the drive must give samples";
  ASSERT_EQ(r.estimates.size(), r.samples.size());
  const pinn::SoilEstimator est = pinn::loadEstimator(modelPath());
  for (std::size_t i = 0; i < r.samples.size(); ++i) {
    SCOPED_TRACE("estimate " + std::to_string(i));
    const soil::PinnSample& s = r.samples[i];
    const SoilEstimateRecord& got = *r.estimates[i];
    EXPECT_EQ(got.sweep_index, s.sweep_index);
    EXPECT_EQ(got.machine_id, "m");
    EXPECT_EQ(got.stamp, s.anchor_stamp);
    EXPECT_LE(got.stamp, got.t1);
    EXPECT_EQ(got.history_T, kT);
    EXPECT_EQ(got.horizon_P, kP);
    const SweepRecord* sweep = nullptr;
    for (const auto& w : r.sweeps)
      if (w->sweep_index == s.sweep_index) sweep = w.get();
    ASSERT_NE(sweep, nullptr);
    EXPECT_TRUE(sweep->fee_valid);
    const pinn::SoilEstimate e = est.estimateFast(s, {1500.0, 0.05});
    expectSameRecord(got, plugins::soilEstimateRecord(*sweep, s, e, 3));
    // The record carries the sweep's geometry and the FEE beta used.
    EXPECT_EQ(got.alpha_rad, sweep->alpha_rad);
    EXPECT_EQ(got.d_m, sweep->d_m);
    // beta at the last horizon step, the members' mean of beta*(their phi, delta; the step's
    // alpha, rho) + their beta_res, recomputed here with the C++ FEE.
    {
      torch::NoGradGuard ng;
      const at::Tensor obs = est.normaliseObs(s.obs.data(), 1, s.T);
      const at::Tensor th = at::from_blob(const_cast<float*>(s.theta_k.data()), {1, s.P, 6}, at::kFloat)
                                .narrow(1, s.P - est.P(), est.P())
                                .contiguous();
      const float* last = s.theta_k.data() + (s.P - 1) * 6;
      double want = 0;
      for (pinn::PinnNet net : est.members()) {
        const pinn::PinnOutput o = net->forward(obs, th);
        const at::Tensor u = o.theta_u[0].to(at::kDouble);
        const fee::Soil soil{u[pinn::kSoilC].item<double>(), u[pinn::kSoilPhi].item<double>(),
                             u[pinn::kSoilGamma].item<double>(), u[pinn::kSoilCa].item<double>(),
                             u[pinn::kSoilDelta].item<double>()};
        const fee::Geometry g{last[pinn::kKAlpha], last[pinn::kKRho], last[pinn::kKD], last[pinn::kKW], last[pinn::kKQ]};
        const double bmin = fee::betaMin(soil, g);
        want += (std::isfinite(bmin) ? bmin : fee::betaNominal(soil)) + o.beta_res[0].item<float>();
      }
      want /= static_cast<double>(est.size());
      EXPECT_NEAR(got.beta_rad, want, 1e-6);  // the member outputs of libtorch vs Eigen, float rounding
      EXPECT_GT(std::abs(got.beta_rad - (M_PI / 4 - got.mean[SoilEstimateRecord::kPhi] / 2 + got.beta_res_rad)), 1e-3)
          << "the test model was trained with beta*, not Rankine's angle";
    }
    EXPECT_EQ(got.members, 3);
    for (int k = 0; k < SoilEstimateRecord::kCount; ++k) {
      EXPECT_TRUE(std::isfinite(got.mean[k]));
      EXPECT_EQ(got.var_total[k], got.var_nullspace[k] + got.var_epistemic[k]);
      EXPECT_GE(got.var_nullspace[k], got.var_aleatoric[k]);
    }
    // The measured force at the horizon end: the blade pushes the soil forward and down.
    EXPECT_GT(got.F_measured[0], 0.0);
    EXPECT_EQ(got.valid, got.invalid_reason.empty());
  }
  // Counters: every sweep is accounted for, as an estimate or a named drop.
  const PluginStats& st = r.soil_report.stats;
  EXPECT_EQ(st.counters.at("estimates"), static_cast<double>(r.samples.size()));
  EXPECT_EQ(st.counters.at("sweeps"), static_cast<double>(r.sweeps.size()));
  long dropped = 0;
  for (const auto& [why, n] : r.skipped) {
    EXPECT_EQ(st.dropped.at("sweep_" + why), n) << why;
    dropped += n;
  }
  EXPECT_EQ(dropped + static_cast<long>(r.samples.size()), static_cast<long>(r.sweeps.size()));
  EXPECT_EQ(r.skipped.count("fee_invalid"), 1u) << "the sweeps above the ground";
  EXPECT_EQ(st.records.size(), r.samples.size());
  EXPECT_EQ(st.dropped.count("sweep_missed"), 0u);
  long invalid = 0;
  for (const auto& e : r.estimates) invalid += e->valid ? 0 : 1;
  EXPECT_EQ(st.counters.count("estimates_invalid") ? st.counters.at("estimates_invalid") : 0.0,
            static_cast<double>(invalid));
  EXPECT_NE(st.records.front().find("\"type\":\"terramap.soil_estimate.v1\""), std::string::npos);
}

TEST(SoilPinnPlugin, ASweepThatCutsNothingPublishesNothingAndSaysFeeInvalid) {
  at::set_num_threads(1);
  const RunResult r = run(airDrive(), 1);
  ASSERT_GE(r.sweeps.size(), 5u);
  for (const auto& w : r.sweeps) EXPECT_FALSE(w->fee_valid);
  EXPECT_TRUE(r.estimates.empty());
  const PluginStats& st = r.soil_report.stats;
  EXPECT_TRUE(st.records.empty());
  ASSERT_EQ(st.dropped.count("sweep_fee_invalid"), 1u);
  EXPECT_EQ(st.dropped.at("sweep_fee_invalid"), static_cast<long>(r.sweeps.size()));
  EXPECT_EQ(st.counters.count("estimates"), 0u);
}

TEST(SoilPinnPlugin, TheObservationBeforeOrAfterTheBladePoseGivesTheSameRecords) {
  at::set_num_threads(1);
  Drive later = cuttingDrive(), earlier = cuttingDrive();
  earlier.observation_first = true;
  const RunResult a = run(later, 1), b = run(earlier, 1);
  ASSERT_FALSE(a.estimates.empty());
  ASSERT_EQ(a.estimates.size(), b.estimates.size());
  for (std::size_t i = 0; i < a.estimates.size(); ++i) {
    SCOPED_TRACE("estimate " + std::to_string(i));
    EXPECT_EQ(a.estimates[i]->stamp, a.estimates[i]->t1) << "the observation at t1 is in the sample";
    expectSameRecord(*a.estimates[i], *b.estimates[i]);
  }
}

TEST(SoilPinnPlugin, BitIdenticalAtOneAndTwoEngineThreads) {
  const RunResult a = run(cuttingDrive(), 1), b = run(cuttingDrive(), 2);
  ASSERT_FALSE(a.estimates.empty());
  ASSERT_EQ(a.estimates.size(), b.estimates.size());
  for (std::size_t i = 0; i < a.estimates.size(); ++i) {
    SCOPED_TRACE("estimate " + std::to_string(i));
    expectSameRecord(*a.estimates[i], *b.estimates[i]);
  }
  EXPECT_EQ(a.soil_report.stats.records, b.soil_report.stats.records);
  EXPECT_EQ(a.soil_report.stats.dropped, b.soil_report.stats.dropped);
}

TEST(SoilPinnPlugin, AMissingModelFileIsAConfigErrorNamingTheFile) {
  const std::string missing = tempPath("no_such_model.pt");
  try {
    makeEngine(1, missing);
    FAIL() << "expected a ConfigError";
  } catch (const ConfigError& e) {
    EXPECT_NE(std::string(e.what()).find(missing), std::string::npos) << e.what();
  }
  // A file that is not a soil estimator.
  const std::string junk = tempPath("junk.pt");
  std::ofstream(junk) << "not a torch archive\n";
  try {
    makeEngine(1, junk);
    FAIL() << "expected a ConfigError";
  } catch (const ConfigError& e) {
    EXPECT_NE(std::string(e.what()).find(junk), std::string::npos) << e.what();
  }
  std::remove(junk.c_str());
  // No model at all: the parameter is required.
  EXPECT_THROW(Engine::prepare("soil", PluginRegistry::createFromFile(std::string(TERRAMAP_PLUGIN_DIR) + "/soil_pinn.so"), {}),
               ConfigError);
}

TEST(SoilPinnPlugin, ARelativeModelPathIsTakenRelativeToThePipelineFolder) {
  // `model` is a path parameter: in a pipeline it is relative to the pipeline's folder (here
  // the model's own folder), whatever the working directory.
  const std::string full = modelPath();
  const std::string folder = full.substr(0, full.rfind('/')), name = full.substr(full.rfind('/') + 1);
  std::map<std::string, RawParam> p;
  p["model"] = RawParam{ParamValue(name), "", false};
  const auto plugin = [] { return PluginRegistry::createFromFile(std::string(TERRAMAP_PLUGIN_DIR) + "/soil_pinn.so"); };
  EXPECT_NO_THROW(Engine::prepare("soil", plugin(), p, {}, nullptr, folder));
  // Without a folder the value is used as given: relative to the working directory (the test
  // runs in the build folder, which holds no such file).
  EXPECT_THROW(Engine::prepare("soil", plugin(), p), ConfigError);
}

TEST(SoilPinnPlugin, HistoryCapacityBelowTheModelsTIsRefused) {
  const auto prepare = [](long cap) {
    std::map<std::string, RawParam> p;
    p["model"] = RawParam{ParamValue(modelPath()), "", false};
    p["history_capacity"] = RawParam{ParamValue(cap), "", false};
    return Engine::prepare("soil", PluginRegistry::createFromFile(std::string(TERRAMAP_PLUGIN_DIR) + "/soil_pinn.so"), p);
  };
  EXPECT_NO_THROW(prepare(0));
  EXPECT_NO_THROW(prepare(kT));
  try {
    prepare(kT - 1);
    FAIL() << "expected a ConfigError";
  } catch (const ConfigError& e) {
    EXPECT_NE(std::string(e.what()).find("history_capacity"), std::string::npos) << e.what();
  }
}

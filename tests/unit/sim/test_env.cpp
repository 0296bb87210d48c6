// The environment API's contracts: levers checked, reset reproducible and restoring the world,
// truncation at the time limit, overrides, and a VectorEnv whose env k equals env k alone.
#include <gtest/gtest.h>

#include <terramap/core/error.hpp>
#include <terramap/sim/env.hpp>

#include <algorithm>
#include <cmath>
#include <cstring>
#include <random>

using namespace terramap;
using namespace terramap::sim;

namespace {

Scenario envScenario() { return loadScenario(std::string(TERRAMAP_SOURCE_DIR) + "/configs/scenarios/env_loader_cut.yaml"); }

std::string errorOf(const std::function<void()>& f) {
  try {
    f();
  } catch (const std::exception& e) {
    return e.what();
  }
  return "";
}

/// A fixed stream of levers in [-1, 1] for environment `k` (forward-biased so the blade cuts).
std::vector<double> levers(std::mt19937_64& rng, std::size_t n) {
  std::uniform_real_distribution<double> U(-1.0, 1.0);
  std::vector<double> a(n);
  for (double& v : a) v = U(rng);
  a[0] = 0.5 + 0.5 * std::abs(a[0]);
  a[1] = 0.5 + 0.5 * std::abs(a[1]);
  return a;
}

bool sameBits(const std::vector<double>& a, const std::vector<double>& b) {
  return a.size() == b.size() && std::memcmp(a.data(), b.data(), a.size() * sizeof(double)) == 0;
}

}  // namespace

TEST(Env, AgentsAreTheExternalMachines) {
  Env env(envScenario());
  ASSERT_EQ(env.agentCount(), 1u);
  EXPECT_EQ(env.agentId(0), "loader");
  EXPECT_EQ(env.actionSize(0), 5u);
  EXPECT_EQ(env.actionNames(0)[2], "blade_lift");
  // Poses, twist, blade, cylinders, tracks, engine, force (3) and the IMU (6).
  EXPECT_EQ(env.observationSize(0), 7u + 6 + 7 + 9 + 3 + 6);
  Scenario none = envScenario();
  none.machines[0].controller.type = ControllerSpec::Type::RandomWalk;
  EXPECT_NE(errorOf([&] { Env e(none); }).find("controller: {type: external}"), std::string::npos);
}

TEST(Env, BadActionsThrowNamingTheLever) {
  Env env(envScenario());
  EXPECT_NE(errorOf([&] { env.step({{0, 0, 0, 0, 0}}); }).find("reset()"), std::string::npos);
  env.reset(1);
  EXPECT_THROW(env.step({{0, 0, 1.5, 0, 0}}), std::invalid_argument);
  const std::string msg = errorOf([&] { env.step({{0, 0, 1.5, 0, 0}}); });
  EXPECT_NE(msg.find("loader"), std::string::npos) << msg;
  EXPECT_NE(msg.find("blade_lift"), std::string::npos) << msg;
  EXPECT_NE(msg.find("1.5"), std::string::npos) << msg;
  EXPECT_NE(errorOf([&] { env.step({{0, NAN, 0, 0, 0}}); }).find("right_track"), std::string::npos);
  EXPECT_NE(errorOf([&] { env.step({{0, 0, 0}}); }).find("takes 5 levers, got 3"), std::string::npos);
  EXPECT_THROW(env.step({}), std::invalid_argument);
  // A rejected action moved nothing: the episode is still at its first period.
  EXPECT_NEAR(env.simulator().time(), 1.0 / 60, 1e-12);
  EXPECT_NO_THROW(env.step({{-1, 1, 0, 0, 0}}));
}

TEST(Env, TruncatedAtTheTimeLimitThenStepThrows) {
  EnvOptions o;
  o.time_limit_s = 0.5;
  o.frame_skip = 3;
  Env env(envScenario(), o);
  StepResult r = env.reset(2);
  EXPECT_FALSE(r.truncated);
  int steps = 0;
  while (!r.truncated) {
    r = env.step({{0.5, 0.5, 0, 0, 0}});
    ++steps;
    ASSERT_LT(steps, 100);
  }
  // The reset's period, then 3 per step: the 30th period (t = 0.5 s) falls in the 10th step.
  EXPECT_EQ(steps, 10);
  EXPECT_DOUBLE_EQ(r.info.t, 0.5);
  EXPECT_FALSE(r.terminated);
  EXPECT_THROW(env.step({{0, 0, 0, 0, 0}}), std::logic_error);
  r = env.reset();
  EXPECT_FALSE(r.truncated);
  EXPECT_NE(r.info.seed, 2u);  // the next seed of the sequence
}

TEST(Env, LeversDriveTheAgentAndTheScriptedMachineKeepsItsRoute) {
  EnvOptions o;
  o.truth = true;
  Env env(envScenario(), o);
  StepResult r = env.reset(3);
  const Eigen::Vector3d p0 = r.observation[0].truth->T_map_base.translation();
  const double grader_x0 = env.simulator().machineTruth(1).T_map_base.translation().x();
  for (int k = 0; k < 120; ++k) r = env.step({{0, 0, 0, 0, 0}});
  EXPECT_LT((r.observation[0].truth->T_map_base.translation() - p0).norm(), 0.01);
  for (int k = 0; k < 120; ++k) r = env.step({{1, 1, 0, 0, 0}});
  const Eigen::Vector3d p1 = r.observation[0].truth->T_map_base.translation();
  EXPECT_GT(p1.x() - p0.x(), 1.0);  // 2 s at up to the machine's full speed
  EXPECT_NEAR(r.observation[0].vector[0], p1.x(), 0.2);  // the localisation's estimate
  EXPECT_GT(r.rewards[0].distance_m, 0.0);
  EXPECT_GT(env.simulator().machineTruth(1).T_map_base.translation().x() - grader_x0, 0.5);
}

TEST(Env, ResetRestoresTheWorldAndReproducesTheEpisode) {
  EnvOptions o;
  o.target = {0.5, -2.5, 4.0, -0.5, 0.08, NAN, NAN};
  auto run = [&](Env& env, std::uint64_t seed, std::vector<double>& trace, std::vector<double>& heights) {
    StepResult r = env.reset(seed);
    std::mt19937_64 rng(seed);
    trace = r.observation[0].vector;
    for (int k = 0; k < 90; ++k) {
      r = env.step(levers(rng, 5).data(), 5);
      trace.insert(trace.end(), r.observation[0].vector.begin(), r.observation[0].vector.end());
      const auto w = r.rewards[0].toVector();
      trace.insert(trace.end(), w.begin(), w.end());
      trace.push_back(r.task.cut_depth_mean_m);
    }
    heights = env.simulator().truth().heightData();
  };
  Env env(envScenario(), o);
  std::vector<double> a, b, c, d, ha, hb, hc, hd;
  run(env, 5, a, ha);
  run(env, 9, b, hb);  // another episode on the changed terrain
  run(env, 5, c, hc);
  Env fresh(envScenario(), o);
  run(fresh, 5, d, hd);
  EXPECT_TRUE(sameBits(a, c));
  EXPECT_TRUE(sameBits(a, d));
  EXPECT_TRUE(sameBits(ha, hc));
  EXPECT_FALSE(sameBits(a, b));
  // The episode changed the terrain (so the restore is tested): the blade cut something.
  double cut = 0;
  for (std::size_t i = 0; i < ha.size(); ++i) cut += std::abs(ha[i] - env.simulator().truth().initialHeight(
                                                                       static_cast<int>(i % env.simulator().truth().nx()),
                                                                       static_cast<int>(i / env.simulator().truth().nx())));
  EXPECT_GT(cut, 1.0);
}

TEST(Env, OverridesMergeByMachineIdAndRebuildOnlyForTerrain) {
  Env env(envScenario());
  StepResult r = env.reset(1);
  EXPECT_TRUE(r.info.rebuilt_terrain);  // the first build
  r = env.reset(1, "machines: [{id: loader, pose: {x_m: 1.0, y_m: -1.5}}]");
  EXPECT_FALSE(r.info.rebuilt_terrain);
  EXPECT_NEAR(r.observation[0].vector[0], 1.0, 0.2);
  EXPECT_EQ(env.scenario().machines[1].id, "grader");  // the other machine untouched
  r = env.reset(1, "terrain: {hills: {seed: 4}}");
  EXPECT_TRUE(r.info.rebuilt_terrain);
  EXPECT_NEAR(r.observation[0].vector[0], 1.0, 0.2);  // earlier overrides stay
  EXPECT_NE(errorOf([&] { env.reset(1, "machines: [{id: dozer, pose: {x_m: 1}}]"); }).find("no machine 'dozer'"),
            std::string::npos);
  const std::string bad = errorOf([&] { env.reset(1, "duration_s: -3"); });
  EXPECT_NE(bad.find("duration_s"), std::string::npos) << bad;
  EXPECT_NO_THROW(env.step({{0, 0, 0, 0, 0}}));  // a bad override left the episode running
}

TEST(Env, TargetSurfaceTermsAndTermination) {
  EnvOptions o;
  // Already reached: a target 5 cm above the initial surface.
  o.target = {1.0, -2.0, 3.0, -1.0, -0.05, NAN, 0.0};
  Env env(envScenario(), o);
  StepResult r = env.reset(1);
  EXPECT_TRUE(r.terminated);
  EXPECT_NEAR(r.task.target_below_m, 0.05, 1e-6);
  EXPECT_THROW(env.step({{0, 0, 0, 0, 0}}), std::logic_error);
  o.target.depth_m = 0.1;
  Env env2(envScenario(), o);
  r = env2.reset(1);
  EXPECT_FALSE(r.terminated);
  EXPECT_NEAR(r.task.target_above_m, 0.1, 1e-6);
  EXPECT_NEAR(r.task.cut_depth_mean_m, 0.0, 1e-6);
}

namespace {

/// Env k's trace (observations, rewards, flags, with its own autoresets) stepped alone.
std::vector<double> aloneTrace(const Scenario& sc, const EnvOptions& o, std::uint64_t seed, int steps) {
  Env env(sc, o);
  StepResult r = env.reset(seed);
  std::mt19937_64 rng(seed * 7919 + 1);
  std::vector<double> t = r.observation[0].vector;
  for (int s = 0; s < steps; ++s) {
    r = env.step(levers(rng, 5).data(), 5);
    const auto w = r.rewards[0].toVector();
    t.insert(t.end(), w.begin(), w.end());
    t.push_back(r.truncated);
    if (r.truncated) r = env.reset();
    t.insert(t.end(), r.observation[0].vector.begin(), r.observation[0].vector.end());
  }
  return t;
}

std::vector<std::vector<double>> batchTraces(const Scenario& sc, const EnvOptions& o, std::uint64_t seed, int n, int threads,
                                             int steps) {
  VectorEnvOptions vo;
  vo.env = o;
  vo.threads = threads;
  VectorEnv v(sc, n, vo);
  v.reset(seed);
  const std::size_t D = v.env(0).observationSize(0), R = RewardTerms::names().size();
  std::vector<std::vector<double>> t(static_cast<std::size_t>(n));
  std::vector<std::mt19937_64> rng;
  for (int k = 0; k < n; ++k) {
    rng.emplace_back((seed + k) * 7919 + 1);
    t[k].assign(v.observations(0).begin() + k * D, v.observations(0).begin() + (k + 1) * D);
  }
  std::vector<double> a(static_cast<std::size_t>(n) * 5);
  for (int s = 0; s < steps; ++s) {
    for (int k = 0; k < n; ++k) {
      const auto l = levers(rng[k], 5);
      std::copy(l.begin(), l.end(), a.begin() + k * 5);
    }
    v.step(a.data(), a.size());
    for (int k = 0; k < n; ++k) {
      t[k].insert(t[k].end(), v.rewards(0).begin() + k * R, v.rewards(0).begin() + (k + 1) * R);
      t[k].push_back(v.truncated()[k]);
      t[k].insert(t[k].end(), v.observations(0).begin() + k * D, v.observations(0).begin() + (k + 1) * D);
    }
  }
  return t;
}

}  // namespace

TEST(VectorEnv, EnvKOfABatchOfEightEqualsEnvKAloneAtOneAndTwoThreads) {
  const Scenario sc = envScenario();
  EnvOptions o;
  o.time_limit_s = 0.5;  // an autoreset inside the run
  o.frame_skip = 2;
  const int steps = 20;
  const auto one = batchTraces(sc, o, 100, 8, 1, steps);
  const auto two = batchTraces(sc, o, 100, 8, 2, steps);
  for (int k : {0, 3, 7}) {
    const auto alone = aloneTrace(sc, o, 100 + k, steps);
    EXPECT_TRUE(sameBits(one[k], alone)) << "env " << k << " at 1 thread";
    EXPECT_TRUE(sameBits(two[k], alone)) << "env " << k << " at 2 threads";
  }
  for (int k = 0; k < 8; ++k) EXPECT_TRUE(sameBits(one[k], two[k])) << "env " << k;
  EXPECT_FALSE(sameBits(one[0], one[1]));
}

TEST(VectorEnv, CloudsAreTheSameBitsInABatch) {
  EnvOptions o;
  o.clouds = true;
  o.frame_skip = 6;  // one scan of the 10 Hz LiDAR per step
  const Scenario sc = envScenario();
  VectorEnvOptions vo;
  vo.env = o;
  vo.threads = 2;
  VectorEnv v(sc, 3, vo);
  v.reset(40);
  Env alone(sc, o);
  alone.reset(42);
  const std::vector<double> a(15, 0.6);
  std::size_t points = 0;
  for (int s = 0; s < 4; ++s) {
    v.step(a.data(), a.size());
    const StepResult r = alone.step(a.data() + 10, 5);
    const auto& c = v.last(2).observation[0].clouds;
    ASSERT_EQ(c.size(), r.observation[0].clouds.size());
    for (std::size_t i = 0; i < c.size(); ++i) {
      ASSERT_EQ(c[i].points.size(), r.observation[0].clouds[i].points.size());
      points += c[i].points.size();
      EXPECT_EQ(std::memcmp(c[i].points.data(), r.observation[0].clouds[i].points.data(),
                            c[i].points.size() * sizeof(PointXYZI)),
                0);
    }
  }
  EXPECT_GT(points, 10000u);
}

TEST(VectorEnv, ABadActionNamesTheEnvironmentAndMovesNone) {
  VectorEnv v(envScenario(), 3);
  v.reset(1);
  std::vector<double> a(15, 0.0);
  a[12] = -2.0;
  const std::string msg = errorOf([&] { v.step(a.data(), a.size()); });
  EXPECT_NE(msg.find("environment 2"), std::string::npos) << msg;
  EXPECT_NE(msg.find("blade_lift"), std::string::npos) << msg;
  for (int k = 0; k < 3; ++k) EXPECT_NEAR(v.times()[k], 1.0 / 60, 1e-12);
}

TEST(Env, ExternalControllerInTheScenario) {
  const std::string base = "version: 1\nname: t\nterrain: {size_m: [8, 8], resolution_m: 0.02}\nmachines:\n";
  // An external controller takes no keys; an excavator may be external.
  const std::string bad = errorOf([&] {
    parseScenario(base + "  - {id: a, pose: {x_m: 0, y_m: 0}, controller: {type: external, speed_mps: 1}}\n", "t.yaml");
  });
  EXPECT_NE(bad.find("speed_mps"), std::string::npos) << bad;
  const Scenario ex = parseScenario(
      base + "  - {id: ex, type: excavator, pose: {x_m: 0, y_m: 0}, controller: {type: external}}\n", "t.yaml");
  auto boomAfter = [&](double lever) {
    Env env(ex);
    EXPECT_EQ(env.actionSize(0), 9u);
    EXPECT_EQ(env.actionNames(0)[6], "boom");
    env.reset(1);
    StepResult r;
    for (int k = 0; k < 60; ++k) r = env.step({{0, 0, 0, 0, 0, 0, lever, 0, 0}});
    const auto& names = env.observationNames(0);
    const std::size_t i = static_cast<std::size_t>(std::find(names.begin(), names.end(), "boom_rad") - names.begin());
    EXPECT_LT(i, names.size());
    EXPECT_EQ(r.observation[0].vector[i], r.observation[0].joints->position_rad[1]);
    return std::make_pair(r.observation[0].vector[i], r.rewards[0].arm_work_j);
  };
  const auto still = boomAfter(0.0), up = boomAfter(1.0);
  EXPECT_GT(up.first - still.first, 0.1);  // one second of full boom lever, rad
  EXPECT_GT(up.second, still.second);
  // Only an external machine takes levers from outside.
  Simulator sim(envScenario());
  EXPECT_NO_THROW(sim.setLevers(0, CtlCommand{}));
  EXPECT_THROW(sim.setLevers(1, CtlCommand{}), ConfigError);
}

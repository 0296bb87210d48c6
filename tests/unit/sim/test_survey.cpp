// The site survey a scenario may start with (`survey:`): points on the initial surface with the
// stated noise, delivered once with the first observation period after the machines' poses,
// the same bits at any thread count, and bad keys named.
#include <gtest/gtest.h>

#include <terramap/core/error.hpp>
#include <terramap/sim/simulator.hpp>
#include <terramap/sim/survey.hpp>

#include <cmath>
#include <cstring>
#include <string>
#include <vector>

using namespace terramap;
using namespace terramap::sim;

namespace {

std::string scenarioYaml(const std::string& survey, int threads) {
  return "version: 1\nseed: 7\nduration_s: 0.5\nthreads: " + std::to_string(threads) +
         "\nterrain: {size_m: [12, 7], origin_m: [-3, -3.5], resolution_m: 0.02,\n"
         "  hills: {count: 4, amplitude_m: [-0.2, 0.3], sigma_m: [0.8, 1.5], seed: 3}}\n" +
         survey +
         "machines:\n  - id: ctl1\n"
         "    controller: {type: route, start_m: [0, 0], length_m: 4, passes: 1, depth_m: 0.05}\n"
         "    sensors:\n      - {id: top, type: lidar, preset: vlp32, columns: 360, offset_m: [0.3, 0, 2.1]}\n";
}

std::vector<PointCloud> surveyOf(const std::vector<Event>& ev) {
  std::vector<PointCloud> out;
  for (const Event& e : ev)
    if (const auto* pc = std::get_if<PointCloud>(&e); pc && pc->frame == "survey") out.push_back(*pc);
  return out;
}

}  // namespace

TEST(Survey, PointsLieOnTheInitialSurfaceWithTheStatedNoiseAndCoverTheSite) {
  const Scenario sc = parseScenario(scenarioYaml("survey: {spacing_m: 0.05, sigma_m: 0.03, block_m: 5}\n", 1), "s.yaml");
  ASSERT_TRUE(sc.survey.enabled());
  Simulator sim(sc);
  const TruthTerrain& t = sim.truth();
  const std::vector<PointCloud> clouds = surveyClouds(sc, t, 1.0);
  // 12 x 7 m in 5 m blocks: 3 x 2 clouds; (12 / 0.05) x (7 / 0.05) squares.
  ASSERT_EQ(clouds.size(), 6u);
  std::size_t n = 0;
  double sum = 0, sum2 = 0;
  for (const PointCloud& pc : clouds) {
    EXPECT_EQ(pc.frame, "survey");
    EXPECT_EQ(pc.stamp, 1.0);
    for (const PointXYZI& p : pc.points) {
      const Eigen::Vector3d m = pc.T_map_sensor * Eigen::Vector3d(p.x, p.y, p.z);
      ASSERT_GE(m.x(), -3.0);
      ASSERT_LE(m.x(), 9.0);
      ASSERT_GE(m.y(), -3.5);
      ASSERT_LE(m.y(), 3.5);
      EXPECT_GE(-p.z, sc.survey.height_m - 1.0);  // the sensor is above the block's highest point
      const double r = m.z() - t.initialHeightAt(m.x(), m.y());
      sum += r;
      sum2 += r * r;
      ++n;
    }
  }
  EXPECT_EQ(n, 240u * 140u);
  const double mean = sum / n, sd = std::sqrt(sum2 / n - mean * mean);
  EXPECT_NEAR(mean, 0.0, 0.002);  // 3 cm / sqrt(33600) = 0.16 mm standard error
  EXPECT_NEAR(sd, 0.03, 0.002);   // float storage adds < 1e-6 m
  // Jittered, not on a lattice: the x positions modulo the spacing spread over the square.
  int low = 0;
  for (const PointXYZI& p : clouds[0].points) {
    const double x = clouds[0].T_map_sensor.translation().x() + p.x + 3.0;
    if (std::fmod(x, 0.05) < 0.025) ++low;
  }
  EXPECT_NEAR(static_cast<double>(low) / clouds[0].points.size(), 0.5, 0.05);
}

TEST(Survey, ComesOnceWithTheFirstPeriodAfterThePosesTheSameBitsAtAnyThreadCount) {
  std::vector<std::vector<PointCloud>> runs;
  for (int threads : {1, 2}) {
    Simulator sim(parseScenario(scenarioYaml("survey: {spacing_m: 0.1}\n", threads), "s.yaml"));
    std::vector<Event> ev;
    ASSERT_TRUE(sim.next(ev));
    bool pose_before = false;
    for (const Event& e : ev) {
      if (std::holds_alternative<Pose>(e)) pose_before = true;
      if (const auto* pc = std::get_if<PointCloud>(&e); pc && pc->frame == "survey") {
        EXPECT_TRUE(pose_before) << "a fusion stage's self-filter needs the machine's pose first";
        EXPECT_EQ(pc->stamp, stampOf(ev.back()));
      }
    }
    runs.push_back(surveyOf(ev));
    EXPECT_EQ(sim.stats().survey_points, 120u * 70u);
    std::size_t later = 0;
    while (sim.next(ev = {})) later += surveyOf(ev).size();
    EXPECT_EQ(later, 0u);
  }
  ASSERT_EQ(runs[0].size(), runs[1].size());
  ASSERT_FALSE(runs[0].empty());
  for (std::size_t k = 0; k < runs[0].size(); ++k) {
    ASSERT_EQ(runs[0][k].points.size(), runs[1][k].points.size());
    EXPECT_TRUE(runs[0][k].T_map_sensor.matrix() == runs[1][k].T_map_sensor.matrix());
    for (std::size_t i = 0; i < runs[0][k].points.size(); ++i)
      ASSERT_EQ(0, std::memcmp(&runs[0][k].points[i], &runs[1][k].points[i], sizeof(PointXYZI)));
  }
}

TEST(Survey, OffByDefaultAndBadKeysAreNamed) {
  Simulator sim(parseScenario(scenarioYaml("", 1), "s.yaml"));
  std::vector<Event> ev;
  ASSERT_TRUE(sim.next(ev));
  EXPECT_TRUE(surveyOf(ev).empty());
  EXPECT_EQ(sim.stats().survey_points, 0u);
  try {
    parseScenario(scenarioYaml("survey: {spacing: 0.1}\n", 1), "s.yaml");
    FAIL() << "expected a ConfigError";
  } catch (const ConfigError& e) {
    EXPECT_NE(std::string(e.what()).find("survey.spacing"), std::string::npos) << e.what();
  }
  try {
    parseScenario(scenarioYaml("survey: {spacing_m: 0}\n", 1), "s.yaml");
    FAIL() << "expected a ConfigError";
  } catch (const ConfigError& e) {
    EXPECT_NE(std::string(e.what()).find("survey.spacing_m"), std::string::npos) << e.what();
  }
}

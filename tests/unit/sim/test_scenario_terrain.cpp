// Scenario loading, soil table, truth terrain queries and ray casting.
#include <gtest/gtest.h>

#include <terramap/core/error.hpp>
#include <terramap/sim/lidar.hpp>
#include <terramap/sim/scenario.hpp>
#include <terramap/soil/soil_table.hpp>
#include <terramap/sim/truth_terrain.hpp>
#include <terramap/sim/world.hpp>

#include <cmath>
#include <fstream>
#include <random>

using namespace terramap;
using namespace terramap::sim;

namespace {
const char* kMinimal = R"(version: 1
seed: 3
duration_s: 1
terrain: {size_m: [4, 4], resolution_m: 0.02}
machines:
  - id: m1
)";

std::string errorOf(const std::string& yaml) {
  try {
    parseScenario(yaml, "s.yaml");
  } catch (const ConfigError& e) {
    return e.what();
  }
  return "";
}
}  // namespace

TEST(SoilTable, InterpolatesBetweenLooseAndDenseEndMembers) {
  // clay: phi 17..27 deg, c 10..70 kPa, gamma 15..20 kN/m3, delta = 0.45 phi, ca = 0.6 c.
  const SoilProperties s = soilProperties(SoilFamily::Clay, 0.5);
  EXPECT_NEAR(s.fee.phi_rad, 22.0 * M_PI / 180, 1e-12);
  EXPECT_NEAR(s.fee.c_pa, 40000.0, 1e-9);
  EXPECT_NEAR(s.fee.gamma_n_m3, 17500.0, 1e-9);
  EXPECT_NEAR(s.fee.delta_rad, 0.45 * 22.0 * M_PI / 180, 1e-12);
  EXPECT_NEAR(s.fee.ca_pa, 24000.0, 1e-9);
  const SoilProperties sand = soilProperties(SoilFamily::Sand, 1.0);
  EXPECT_NEAR(sand.fee.phi_rad, 43.0 * M_PI / 180, 1e-12);
  EXPECT_EQ(sand.fee.c_pa, 0.0);
  EXPECT_THROW(soilProperties(SoilFamily::Loam, 1.2), std::invalid_argument);
  SoilFamily f{};
  EXPECT_TRUE(parseSoilFamily("gravel", f));
  EXPECT_EQ(f, SoilFamily::Gravel);
  EXPECT_FALSE(parseSoilFamily("peat", f));
}

TEST(Scenario, MinimalGetsDocumentedDefaults) {
  const Scenario sc = parseScenario(kMinimal, "s.yaml");
  ASSERT_EQ(sc.machines.size(), 1u);
  EXPECT_DOUBLE_EQ(sc.machines[0].blade.width_m, 1.85);
  EXPECT_DOUBLE_EQ(sc.machines[0].blade.height_m, 0.76);
  EXPECT_DOUBLE_EQ(sc.terrain.origin_x_m, -2.0);
  EXPECT_EQ(sc.seed, 3u);
}

TEST(Scenario, UnknownKeyNamesLineColumnAndSuggestion) {
  const std::string yaml = std::string(kMinimal) + "duraton_s: 4\n";
  const std::string e = errorOf(yaml);
  EXPECT_NE(e.find("s.yaml:7:1"), std::string::npos) << e;
  EXPECT_NE(e.find("did you mean 'duration_s'"), std::string::npos) << e;
}

TEST(Scenario, BadValuesAreReportedWithKeyPath) {
  std::string e = errorOf(std::string(kMinimal) + "soil: {default: {family: cley, relative_density: 0.2}}\n");
  EXPECT_NE(e.find("soil.default.family"), std::string::npos) << e;
  EXPECT_NE(e.find("did you mean 'clay'"), std::string::npos) << e;
  e = errorOf(std::string(kMinimal) + "soil: {default: {family: clay, relative_density: 1.5}}\n");
  EXPECT_NE(e.find("out of range"), std::string::npos) << e;
  e = errorOf("version: 1\nterrain: {size_m: [4, 4], resolution_m: 0.05}\nmachines: [{id: a}]\n");
  EXPECT_NE(e.find("s.yaml:2:"), std::string::npos) << e;
  EXPECT_NE(e.find("terrain.resolution_m"), std::string::npos) << e;
  e = errorOf("version: 1\nterrain: {size_m: [4, 4]}\n");
  EXPECT_NE(e.find("machines"), std::string::npos) << e;
  e = errorOf(std::string(kMinimal) + "    sensors: [{id: l, type: lidar, preset: os1_46}]\n");
  EXPECT_NE(e.find("did you mean 'os1_64'"), std::string::npos) << e;
}

TEST(Scenario, SoilZonesOverrideInOrderAndByDepth) {
  const Scenario sc = parseScenario(std::string(kMinimal) + R"(soil:
  default: {family: loam, relative_density: 0.5}
  zones:
    - {family: sand, relative_density: 0.2, strip: {axis: x, range_m: [0, 1]}}
    - {family: clay, relative_density: 0.9, depth_m: [0.3, .inf]}
    - {family: gravel, relative_density: 0.4, polygon: [[-1, -1], [-0.5, -1], [-0.5, -0.5]]}
)",
                                    "s.yaml");
  const SoilField f(sc.default_soil, sc.zones);
  EXPECT_EQ(f.at(0.5, 0, 0.1).family, SoilFamily::Sand);
  EXPECT_EQ(f.at(0.5, 0, 0.5).family, SoilFamily::Clay);   // later zone wins
  EXPECT_EQ(f.at(-1.5, 0, 0.1).family, SoilFamily::Loam);  // default
  EXPECT_EQ(f.at(-0.6, -0.9, 0.0).family, SoilFamily::Gravel);
  EXPECT_EQ(f.at(-0.9, -0.6, 0.0).family, SoilFamily::Loam);  // other side of the diagonal
}

TEST(Scenario, ADippingStratumShiftsItsDepthRangeAcrossTheSite) {
  const Scenario sc = parseScenario(std::string(kMinimal) + R"(soil:
  default: {family: loam, relative_density: 0.2}
  zones:
    - {family: clay, relative_density: 0.8, depth_m: [0.3, .inf], depth_dip: [0.02, -0.01]}
)",
                                    "s.yaml");
  const SoilField f(sc.default_soil, sc.zones);
  // At (5, 0) the top lies at 0.3 + 0.1 = 0.4 m; at (0, 10) at 0.3 - 0.1 = 0.2 m.
  EXPECT_EQ(f.at(5, 0, 0.38).family, SoilFamily::Loam);
  EXPECT_EQ(f.at(5, 0, 0.42).family, SoilFamily::Clay);
  EXPECT_EQ(f.at(0, 10, 0.18).family, SoilFamily::Loam);
  EXPECT_EQ(f.at(0, 10, 0.22).family, SoilFamily::Clay);
  EXPECT_DOUBLE_EQ(sc.zones[0].depthMinAt(5, 10), 0.3);
}

TEST(Terrain, EsriAsciiDemIsReadAndSampled) {
  const std::string path = std::string(TERRAMAP_BINARY_DIR) + "/sim_test_dem.asc";
  {
    std::ofstream o(path);
    o << "ncols 3\nnrows 2\nxllcorner 0\nyllcorner 0\ncellsize 1\nNODATA_value -9999\n";
    o << "4 5 6\n1 2 3\n";  // north row first
  }
  const DemGrid g = readEsriAscii(path);
  EXPECT_EQ(g.nx, 3);
  EXPECT_EQ(g.ny, 2);
  EXPECT_DOUBLE_EQ(g.x0_m, 0.5);                  // cell centre
  EXPECT_DOUBLE_EQ(g.heightAt(0.5, 0.5), 1.0);    // south-west value
  EXPECT_DOUBLE_EQ(g.heightAt(1.0, 1.0), 3.0);    // mean of 1, 2, 4, 5
  {
    std::ofstream o(path);
    o << "ncols 2\nnrows 2\nxllcorner 0\nyllcorner 0\ncellsize 1\n1 2\n3 x\n";
  }
  try {
    readEsriAscii(path);
    FAIL();
  } catch (const InputError& e) {
    EXPECT_NE(std::string(e.what()).find("row 2, column 2"), std::string::npos) << e.what();
  }
}

TEST(Terrain, BilinearIsExactOnAPlane) {
  TerrainSpec s;
  s.size_x_m = 2; s.size_y_m = 1; s.resolution_m = 0.02; s.origin_x_m = 0; s.origin_y_m = 0;
  s.slope_x = 0.1; s.slope_y = -0.05; s.base_height_m = 1.0;
  const TruthTerrain t = buildTerrain(s);
  EXPECT_NEAR(t.heightAt(0.731, 0.417), 1.0 + 0.0731 - 0.02085, 1e-12);
  const Eigen::Vector2d g = t.gradientAt(1.3, 0.2);
  EXPECT_NEAR(g.x(), 0.1, 1e-9);
  EXPECT_NEAR(g.y(), -0.05, 1e-9);
  EXPECT_TRUE(std::isnan(t.heightAt(-0.01, 0.5)));
}

TEST(Raycast, HitsAnAnalyticPlaneExactly) {
  TerrainSpec s;
  s.size_x_m = 10; s.size_y_m = 10; s.resolution_m = 0.02; s.origin_x_m = -5; s.origin_y_m = -5;
  s.slope_x = 0.2; s.slope_y = 0.1; s.base_height_m = 0.0;
  const TruthTerrain t = buildTerrain(s);
  // Plane z = 0.2 (x + 5) + 0.1 (y + 5); ray o + t d: solve o_z + t d_z = 0.2(o_x + t d_x + 5) + 0.1(o_y + t d_y + 5).
  std::mt19937_64 rng(5);
  std::uniform_real_distribution<double> U(-1, 1);
  int hits = 0;
  for (int k = 0; k < 500; ++k) {
    const Eigen::Vector3d o(U(rng) * 2, U(rng) * 2, 4.0);
    const Eigen::Vector3d d = Eigen::Vector3d(U(rng), U(rng), -0.4 - std::abs(U(rng))).normalized();
    const double expect = (0.2 * (o.x() + 5) + 0.1 * (o.y() + 5) - o.z()) / (d.z() - 0.2 * d.x() - 0.1 * d.y());
    const double got = t.raycast(o, d, 0.0, 100.0);
    const Eigen::Vector3d p = o + d * expect;
    if (std::abs(p.x()) < 4.99 && std::abs(p.y()) < 4.99) {
      ASSERT_NEAR(got, expect, 1e-9) << k;
      ++hits;
    }
  }
  EXPECT_GT(hits, 400);
  // Upward ray and ray limited before the surface miss.
  EXPECT_TRUE(std::isnan(t.raycast({0, 0, 4}, {0, 0, 1}, 0, 100)));
  EXPECT_TRUE(std::isnan(t.raycast({0, 0, 4}, {0, 0, -1}, 0, 1.0)));
}

TEST(Raycast, HitsASphereCapWithinInterpolationError) {
  // Terrain = upper half of a sphere of radius R centred at c (z = 0 elsewhere).
  const double R = 1.0, res = 0.01;
  const Eigen::Vector3d c(0, 0, -0.5);
  TruthTerrain t(-2, -2, res, 401, 401, 0.0);
  for (int j = 0; j < t.ny(); ++j)
    for (int i = 0; i < t.nx(); ++i) {
      const Eigen::Vector2d p = t.nodePosition(i, j);
      const double r2 = p.squaredNorm();
      t.setUndisturbed(i, j, r2 < R * R ? std::max(0.0, c.z() + std::sqrt(R * R - r2)) : 0.0);
    }
  t.captureInitial();
  t.refreshPyramid();
  std::mt19937_64 rng(11);
  std::uniform_real_distribution<double> U(-1, 1);
  double worst = 0;  // largest |error| / bound over the rays
  for (int k = 0; k < 300; ++k) {
    const Eigen::Vector3d o(U(rng) * 3, U(rng) * 3, 3.0);
    const Eigen::Vector3d target(U(rng) * 0.5, U(rng) * 0.5, 0.2);
    const Eigen::Vector3d d = (target - o).normalized();
    // Analytic: |o + t d - c|^2 = R^2, nearest root.
    const Eigen::Vector3d oc = o - c;
    const double b = oc.dot(d), cc = oc.squaredNorm() - R * R;
    const double disc = b * b - cc;
    ASSERT_GT(disc, 0);
    const double expect = -b - std::sqrt(disc);
    const double got = t.raycast(o, d, 0, 10);
    // The terrain is the bilinear interpolant of the cap's nodes. Bilinear interpolation on
    // h x h cells is off by at most h^2/8 (max|f_xx| + max|f_yy|) (the linear-interpolation
    // error along each axis); for the cap f = c_z + sqrt(R^2 - r^2), |f_xx| <= R^2 / s^(3/2)
    // with s = R^2 - r^2, largest at the cell's outer corner (r + sqrt(2) h). A vertical error
    // dz moves the hit along the ray by dz / |d_z - grad f . d_xy| (the rate at which the ray
    // closes on the surface there). Plus 1e-9 m of arithmetic.
    const Eigen::Vector3d p = o + expect * d;
    const double r = std::hypot(p.x(), p.y()), r_out = r + std::sqrt(2.0) * res;
    ASSERT_LT(r_out, std::sqrt(R * R - c.z() * c.z()));  // on the smooth cap, not at its clipped rim
    const double s_out = R * R - r_out * r_out;
    const double dz_max = res * res / 8.0 * 2.0 * R * R / std::pow(s_out, 1.5);
    const double sp = std::sqrt(R * R - r * r);
    const Eigen::Vector2d grad(-p.x() / sp, -p.y() / sp);
    const double closing = std::abs(d.z() - grad.dot(d.head<2>()));
    ASSERT_NEAR(got, expect, dz_max / closing + 1e-9) << k << " closing rate " << closing;
    worst = std::max(worst, std::abs(got - expect) / (dz_max / closing));
  }
  // The bound is tight, not a loose allowance: the worst ray comes within a factor 2 of it.
  EXPECT_GT(worst, 0.5);
}

TEST(Raycast, PyramidAgreesWithBruteForceOnRoughTerrain) {
  TerrainSpec s;
  s.size_x_m = 3; s.size_y_m = 2; s.resolution_m = 0.02; s.origin_x_m = 0; s.origin_y_m = 0;
  std::mt19937_64 rng(2);
  std::uniform_real_distribution<double> U(0, 1);
  for (int k = 0; k < 40; ++k) s.bumps.push_back({U(rng) * 3, U(rng) * 2, (U(rng) - 0.5) * 0.6, 0.05 + U(rng) * 0.3});
  const TruthTerrain t = buildTerrain(s);
  int hits = 0;
  for (int k = 0; k < 400; ++k) {
    const Eigen::Vector3d o(U(rng) * 3, U(rng) * 2, 0.5 + U(rng));
    const Eigen::Vector3d d = Eigen::Vector3d(U(rng) - 0.5, U(rng) - 0.5, -0.05 - 0.5 * U(rng)).normalized();
    const double a = t.raycast(o, d, 0.1, 20), b = t.raycastReference(o, d, 0.1, 20);
    ASSERT_EQ(std::isnan(a), std::isnan(b)) << k;
    if (!std::isnan(a)) {
      ASSERT_NEAR(a, b, 1e-12) << k;
      ++hits;
      // The hit lies on the surface.
      const Eigen::Vector3d p = o + d * a;
      ASSERT_NEAR(p.z(), t.heightAt(p.x(), p.y()), 1e-9);
    }
  }
  EXPECT_GT(hits, 100);
}

TEST(Lidar, PointsLieOnAPlaneAndCountsMatchGeometry) {
  TerrainSpec s;
  s.size_x_m = 60; s.size_y_m = 60; s.resolution_m = 0.02; s.base_height_m = 0.0;
  s.origin_x_m = -30; s.origin_y_m = -30;
  const TruthTerrain t = buildTerrain(s);
  SensorSpec ss;
  applyLidarPreset("vlp32", ss);
  ss.range_noise_m = 0;
  ss.columns = 360;
  const LidarModel L(ss);
  Eigen::Isometry3d T = Eigen::Isometry3d::Identity();
  T.translation() = Eigen::Vector3d(0, 0, 2.0);
  std::vector<PointXYZI> pts;
  L.scan(t, T, 1, nullptr, pts);
  // Expected hits from the analytic plane z = 0: a ray with d_z < 0 hits at range 2 / -d_z; it
  // counts if that range is within [min, max] and the ground point lies inside the grid.
  std::size_t expect = 0;
  for (const Eigen::Vector3d& d : L.directions()) {
    if (d.z() >= 0) continue;
    const double r = 2.0 / -d.z();
    const double x = d.x() * r, y = d.y() * r;
    if (r >= ss.min_range_m && r <= ss.max_range_m && std::abs(x) <= 30.0 && std::abs(y) <= 30.0) ++expect;
  }
  EXPECT_EQ(pts.size(), expect);
  EXPECT_GT(expect, 5000u);
  for (const auto& p : pts) ASSERT_NEAR(p.z + 2.0f, 0.0f, 1e-4f);
}

TEST(Lidar, NoiseAndDropoutsAreSeededAndThreadIndependent) {
  TerrainSpec s;
  s.size_x_m = 20; s.size_y_m = 20; s.origin_x_m = -10; s.origin_y_m = -10; s.resolution_m = 0.02;
  s.bumps.push_back({2, 1, 0.4, 1.0});
  const TruthTerrain t = buildTerrain(s);
  SensorSpec ss;
  applyLidarPreset("os1_64", ss);
  ss.dropout = 0.1;
  const LidarModel L(ss);
  Eigen::Isometry3d T = Eigen::Isometry3d::Identity();
  T.translation() = Eigen::Vector3d(0, 0, 2.0);
  std::vector<PointXYZI> a, b, c;
  Executor ex2(2);
  L.scan(t, T, 77, nullptr, a);
  L.scan(t, T, 77, &ex2, b);
  L.scan(t, T, 78, &ex2, c);
  ASSERT_EQ(a.size(), b.size());
  EXPECT_EQ(0, std::memcmp(a.data(), b.data(), a.size() * sizeof(PointXYZI)));
  EXPECT_NE(a.size() == c.size() && std::memcmp(a.data(), c.data(), a.size() * sizeof(PointXYZI)) == 0, true);
  // Noise has the configured spread: residual along the ray vs the noiseless hit.
  double s2 = 0;
  int n = 0;
  SensorSpec quiet = ss;
  quiet.range_noise_m = 0;
  quiet.dropout = 0;
  quiet.keep_dropouts = true;
  SensorSpec noisy = ss;
  noisy.dropout = 0;
  noisy.keep_dropouts = true;
  std::vector<PointXYZI> q, z;
  LidarModel(quiet).scan(t, T, 5, nullptr, q);
  LidarModel(noisy).scan(t, T, 5, nullptr, z);
  ASSERT_EQ(q.size(), z.size());
  for (std::size_t k = 0; k < q.size(); ++k) {
    if (std::isnan(q[k].x)) continue;
    const double r0 = std::sqrt(q[k].x * q[k].x + q[k].y * q[k].y + q[k].z * q[k].z);
    const double r1 = std::sqrt(z[k].x * z[k].x + z[k].y * z[k].y + z[k].z * z[k].z);
    s2 += (r1 - r0) * (r1 - r0);
    ++n;
  }
  ASSERT_GT(n, 10000);
  EXPECT_NEAR(std::sqrt(s2 / n), ss.range_noise_m, 0.1 * ss.range_noise_m);
}

TEST(LidarNoise, HashGaussianIsStandardNormal) {
  // The ziggurat sampler behind the range noise, fed the same per-ray hashes as a scan: moments
  // and the normal CDF at several points (incl. both tails past the base layer at 3.44).
  const int n = 2000000;
  double s1 = 0, s2 = 0, s4 = 0;
  const double cuts[] = {-3.6, -1.96, -1.0, 0.0, 1.0, 1.96, 3.6};
  long below[7] = {0, 0, 0, 0, 0, 0, 0};
  for (int k = 0; k < n; ++k) {
    const double x = gaussianFromBits(mixBits(12345 ^ mixBits(static_cast<std::uint64_t>(k))));
    ASSERT_TRUE(std::isfinite(x));
    s1 += x;
    s2 += x * x;
    s4 += x * x * x * x;
    for (int c = 0; c < 7; ++c) below[c] += x < cuts[c];
  }
  EXPECT_NEAR(s1 / n, 0.0, 0.004);
  EXPECT_NEAR(s2 / n, 1.0, 0.005);
  EXPECT_NEAR(s4 / n, 3.0, 0.03);
  for (int c = 0; c < 7; ++c) {
    const double p = 0.5 * std::erfc(-cuts[c] / std::sqrt(2.0));
    EXPECT_NEAR(static_cast<double>(below[c]) / n, p, 5.0 * std::sqrt(p * (1 - p) / n) + 1e-6) << "x < " << cuts[c];
  }
}

// The soil estimator's dataset (eval/soil_dataset.hpp): planning, held-out separation,
// determinism across thread counts, and the HDF5 round trip of a real (short) episode.
#include <terramap/core/error.hpp>
#include <terramap/eval/soil_dataset.hpp>
#include <terramap/soil/soil_table.hpp>

#include <gtest/gtest.h>

#include <cmath>
#include <filesystem>
#include <fstream>
#include <iterator>
#include <unistd.h>

using namespace terramap;
using namespace terramap::eval;
namespace fs = std::filesystem;

namespace {

std::string configText(int episodes, int held, double duration, const std::string& extra = "") {
  const std::string dir = std::string(TERRAMAP_SOURCE_DIR) + "/configs/dataset/";
  return "version: 1\nseed: 5\nepisodes: " + std::to_string(episodes) + "\nduration_s: " + std::to_string(duration) +
         "\nhistory: {T: 30, P: 10}\nheld_out: {episodes: " + std::to_string(held) +
         ", family: gravel, relative_density: [0.7, 1.0], rake_deg: 68}\n"
         "scenario: " + dir + "pinn_episode.yaml\npipeline: " + dir + "pinn_pipeline.yaml\n" + extra;
}

SoilDatasetConfig config(int episodes, int held, double duration, const std::string& extra = "") {
  return parseSoilDatasetConfig(configText(episodes, held, duration, extra), "test.yaml", ".");
}

}  // namespace

TEST(SoilDataset, HeldOutSoilAndRakeAreNeverDrawnInDistribution) {
  const SoilDatasetConfig cfg = config(4000, 200, 10);
  int gravel = 0, counts[3] = {0, 0, 0};
  for (int i = 0; i < cfg.episodes; ++i) {
    const EpisodePlan p = planEpisode(cfg, i);
    ASSERT_NE(p.split, DatasetSplit::HeldOut);
    ++counts[static_cast<int>(p.split)];
    EXPECT_GE(p.rake_rad, 75 * M_PI / 180 - 1e-12);
    EXPECT_LE(p.rake_rad, 85 * M_PI / 180 + 1e-12);
    if (p.family == soil::SoilFamily::Gravel) {
      ++gravel;
      EXPECT_TRUE(p.relative_density < 0.7 || p.relative_density > 1.0) << p.relative_density;
    }
    EXPECT_GE(p.relative_density, 0.01);
    EXPECT_LE(p.relative_density, 1.0);
  }
  EXPECT_GT(gravel, 800);  // a quarter of 4000, give or take sampling (sd ~ 27)
  // 15 % validation and test each: 600 expected, binomial sd ~ 23.
  EXPECT_NEAR(counts[1], 600, 5 * 23);
  EXPECT_NEAR(counts[2], 600, 5 * 23);
  for (int i = cfg.episodes; i < episodeCount(cfg); ++i) {
    const EpisodePlan p = planEpisode(cfg, i);
    EXPECT_EQ(p.split, DatasetSplit::HeldOut);
    EXPECT_EQ(p.family, soil::SoilFamily::Gravel);
    EXPECT_GE(p.relative_density, 0.7);
    EXPECT_NEAR(p.rake_rad, 68 * M_PI / 180, 1e-12);
  }
  EXPECT_THROW(planEpisode(cfg, episodeCount(cfg)), std::out_of_range);
}

TEST(SoilDataset, AnEpisodesPlanDependsOnlyOnTheSeedAndItsIndex) {
  const SoilDatasetConfig a = config(10, 5, 10), b = config(300, 50, 10);
  for (int i = 0; i < 10; ++i) {
    const EpisodePlan pa = planEpisode(a, i), pb = planEpisode(b, i);
    EXPECT_EQ(pa.seed, pb.seed);
    EXPECT_EQ(pa.relative_density, pb.relative_density);
    EXPECT_EQ(episodeFileName(pa), episodeFileName(pb));
  }
  // Held-out episode j is the same whatever the number of in-distribution episodes.
  for (int j = 0; j < 5; ++j) {
    const EpisodePlan pa = planEpisode(a, 10 + j), pb = planEpisode(b, 300 + j);
    EXPECT_EQ(pa.seed, pb.seed);
    EXPECT_EQ(pa.relative_density, pb.relative_density);
    EXPECT_EQ(episodeFileName(pa), episodeFileName(pb));
    EXPECT_EQ(episodeFileName(pa).rfind("held_", 0), 0u);
  }
  // Another seed, other episodes.
  const SoilDatasetConfig c = parseSoilDatasetConfig(
      [&] { std::string t = configText(10, 5, 10); t.replace(t.find("seed: 5"), 7, "seed: 6"); return t; }(), "c.yaml", ".");
  EXPECT_NE(planEpisode(c, 0).seed, planEpisode(a, 0).seed);
}

// route_fraction: that share of the episodes is graded by one route pass holding the edge at a
// grade below the ground ahead of the machine; every other draw of every plan stays as it was.
TEST(SoilDataset, GradedEpisodesTakeTheirShareAndLeaveTheOtherDrawsAlone) {
  const SoilDatasetConfig plain = config(400, 40, 10), mixed = config(400, 40, 10, "route_fraction: 0.3\n");
  int routes = 0;
  for (int i = 0; i < episodeCount(plain); ++i) {
    const EpisodePlan a = planEpisode(plain, i), b = planEpisode(mixed, i);
    EXPECT_FALSE(a.route);
    routes += b.route;
    EXPECT_EQ(a.seed, b.seed);
    EXPECT_EQ(a.hill_seed, b.hill_seed);
    EXPECT_EQ(a.relative_density, b.relative_density);
    EXPECT_EQ(a.initial_setpoints, b.initial_setpoints);
    const sim::Scenario sa = episodeScenario(plain, a), sb = episodeScenario(mixed, b);
    const sim::ControllerSpec &ca = sa.machines[0].controller, &cb = sb.machines[0].controller;
    EXPECT_EQ(ca.type, sim::ControllerSpec::Type::RandomWalk);
    if (!b.route) {
      EXPECT_EQ(cb.type, sim::ControllerSpec::Type::RandomWalk);
      continue;
    }
    ASSERT_EQ(cb.type, sim::ControllerSpec::Type::Route);
    EXPECT_TRUE(cb.route_grade);
    EXPECT_EQ(cb.route_passes, 1);
    EXPECT_EQ(cb.grade_step_m, 0.0);
    EXPECT_EQ(cb.route_speed_mps, ca.speed_mps.initial);
    EXPECT_GE(cb.route_length_m, cb.route_speed_mps * 10);  // the whole episode forward
    EXPECT_NEAR(cb.route_heading_rad, ca.heading_rad.initial, 1e-12);  // the base scenario starts at yaw 0
    // The grade lies the set-point depth (at least 3 cm) below the ground under the blade's start.
    const sim::MachineSpec& m = sb.machines[0];
    const Eigen::Vector2d edge =
        cb.route_start + m.blade_mount_x_m * Eigen::Vector2d(std::cos(cb.route_heading_rad), std::sin(cb.route_heading_rad));
    double ground = sb.terrain.base_height_m;
    for (const sim::GaussianBump& h : sb.terrain.bumps)
      ground += h.amplitude_m * std::exp(-0.5 * (edge - Eigen::Vector2d(h.x_m, h.y_m)).squaredNorm() / (h.sigma_m * h.sigma_m));
    EXPECT_NEAR(ground - cb.grade_first_m, std::max(0.03, ca.depth_m.initial), 1e-9);
  }
  // 30 % of 440: 132 expected, binomial sd ~ 9.6.
  EXPECT_NEAR(routes, 132, 5 * 9.6);
  EXPECT_THROW(config(10, 2, 10, "route_fraction: 1.5\n"), ConfigError);
  // A graded episode runs through the mapping pipeline and gives samples of a cut.
  const SoilDatasetConfig graded = config(1, 0, 5.0, "route_fraction: 1.0\n");
  const EpisodePlan plan = planEpisode(graded, 0);
  ASSERT_TRUE(plan.route);
  const EpisodeData ep = runDatasetEpisode(graded, plan, 1);
  ASSERT_GT(ep.samples.size(), 2u) << "sweeps " << ep.sweeps;
  for (const auto& smp : ep.samples)
    for (float f : smp.force) EXPECT_TRUE(std::isfinite(f));
}

TEST(SoilDataset, ConfigErrorsNameTheFileLineAndKey) {
  try {
    parseSoilDatasetConfig(configText(10, 2, 10, "rake_deg: [60, 75]\nhistory_typo: 1\n"), "bad.yaml", ".");
    FAIL() << "no error";
  } catch (const ConfigError& e) {
    const std::string m = e.what();
    EXPECT_NE(m.find("bad.yaml:"), std::string::npos) << m;
    EXPECT_NE(m.find("held_out.rake_deg"), std::string::npos) << m;  // 68 lies inside [60, 75]
    EXPECT_NE(m.find("history_typo"), std::string::npos) << m;
  }
  EXPECT_THROW(parseSoilDatasetConfig(
                   [] { std::string t = configText(10, 2, 10); t.replace(t.find("P: 10"), 5, "P: 40"); return t; }(),
                   "p.yaml", "."),
               ConfigError);
}

// One short real episode through the simulator and the mapping pipeline: samples exist, their
// truth is the episode's soil, the forces are finite and push forward, and the result is the
// same bits with 1 and 2 threads.
TEST(SoilDataset, ShortEpisodeIsDeterministicAndRoundTripsThroughHdf5) {
  const SoilDatasetConfig cfg = config(1, 0, 6.0);
  const EpisodePlan plan = planEpisode(cfg, 0);
  const EpisodeData one = runDatasetEpisode(cfg, plan, 1);
  const EpisodeData two = runDatasetEpisode(cfg, plan, 2);
  std::string why;
  for (const auto& [k, v] : one.skipped) why += " " + k + "=" + std::to_string(v);
  ASSERT_GT(one.samples.size(), 2u) << "sweeps " << one.sweeps << ", skipped:" << why;
  ASSERT_EQ(one.samples.size(), two.samples.size());
  for (std::size_t i = 0; i < one.samples.size(); ++i) {
    EXPECT_EQ(one.samples[i].obs, two.samples[i].obs);
    EXPECT_EQ(one.samples[i].theta_k, two.samples[i].theta_k);
    EXPECT_EQ(one.samples[i].force, two.samples[i].force);
  }
  const soil::SoilProperties truth = soil::soilProperties(plan.family, plan.relative_density);
  for (std::size_t i = 0; i < one.samples.size(); ++i) {
    EXPECT_FLOAT_EQ(one.truth[i][1], static_cast<float>(truth.fee.phi_rad));
    EXPECT_FLOAT_EQ(one.truth[i][4], static_cast<float>(truth.fee.gamma_n_m3));
    for (float f : one.samples[i].force) EXPECT_TRUE(std::isfinite(f));
  }
  // While cutting the blade pushes the soil forward: the mean force along t_hat is positive.
  double fx = 0;
  for (const auto& s : one.samples) fx += s.force[0];
  EXPECT_GT(fx / static_cast<double>(one.samples.size()), 0.0);

  const fs::path dir = fs::temp_directory_path() / ("terramap_soil_dataset_" + std::to_string(::getpid()));
  fs::create_directories(dir / "episodes");
  writeEpisodeFile((dir / "episodes" / episodeFileName(plan)).string(), cfg, one);
  const SoilDataset d = readSoilDataset(dir.string());
  ASSERT_EQ(d.size(), one.samples.size());
  EXPECT_EQ(d.T, 30);
  EXPECT_EQ(d.P, 10);
  EXPECT_EQ(d.config_hash, cfg.config_hash);
  for (std::size_t i = 0; i < d.size(); ++i) {
    const auto& s = one.samples[i];
    EXPECT_TRUE(std::equal(s.obs.begin(), s.obs.end(), d.obs.begin() + static_cast<long>(i * s.obs.size())));
    EXPECT_TRUE(std::equal(s.force.begin(), s.force.end(), d.force.begin() + static_cast<long>(i * s.force.size())));
    EXPECT_TRUE(std::equal(one.force_quiet[i].begin(), one.force_quiet[i].end(),
                           d.force_quiet.begin() + static_cast<long>(i * s.force.size())));
    EXPECT_EQ(d.split[i], static_cast<std::uint8_t>(plan.split));
  }
  const std::string manifest = datasetManifestJson(dir.string());
  EXPECT_NE(manifest.find("\"samples\": " + std::to_string(one.samples.size())), std::string::npos) << manifest;
  fs::remove_all(dir);
}

// The noise-free force kept beside each sample row (EpisodeData::force_quiet, the floor of every
// force error): with the soil's coloured noise and the sensor's switched off it is the measured
// force of the same row, to the rounding of the frames it went through; with them on it differs
// by about the noise (docs/soil_estimator.md, "The force noise floor"). The noise-free force
// handed to the sensor in the map frame instead of the base frame puts it 8.5 % off.
TEST(SoilDataset, EachRowKeepsTheForceWithoutItsNoise) {
  const fs::path dir = fs::temp_directory_path() / ("terramap_soil_dataset_quiet_" + std::to_string(::getpid()));
  fs::create_directories(dir);
  const std::string src = std::string(TERRAMAP_SOURCE_DIR) + "/configs/dataset/";
  std::ifstream in(src + "pinn_episode.yaml");
  std::string yaml((std::istreambuf_iterator<char>(in)), std::istreambuf_iterator<char>());
  const auto replace = [&](const std::string& from, const std::string& to) {
    const auto at = yaml.find(from);
    ASSERT_NE(at, std::string::npos) << from;
    yaml.replace(at, from.size(), to);
  };
  replace("    blade: {width_m", "    force_noise: {abs_n: 0, rel: 0}\n    blade: {width_m");
  replace("noise_abs_n: 100, noise_rel: 0.02", "noise_abs_n: 0, noise_rel: 0");
  std::ofstream((dir / "quiet.yaml").string()) << yaml;
  const auto text = [&](const std::string& scenario) {
    return "version: 1\nseed: 5\nepisodes: 1\nduration_s: 6\nhistory: {T: 30, P: 10}\n"
           "held_out: {episodes: 0, family: gravel, relative_density: [0.7, 1.0], rake_deg: 68}\n"
           "scenario: " + scenario + "\npipeline: " + src + "pinn_pipeline.yaml\n";
  };
  const auto run = [&](const std::string& scenario, double& rel_diff, long& rows) {
    const SoilDatasetConfig cfg = parseSoilDatasetConfig(text(scenario), "q.yaml", ".");
    const EpisodeData ep = runDatasetEpisode(cfg, planEpisode(cfg, 0), 1);
    ASSERT_GT(ep.samples.size(), 2u);
    ASSERT_EQ(ep.force_quiet.size(), ep.samples.size());
    double diff = 0, norm = 0;
    rows = 0;
    for (std::size_t i = 0; i < ep.samples.size(); ++i) {
      ASSERT_EQ(ep.force_quiet[i].size(), ep.samples[i].force.size());
      for (std::size_t p = 0; p + 1 < ep.samples[i].force.size(); p += 2) {
        const float* q = &ep.force_quiet[i][p];
        const float* f = &ep.samples[i].force[p];
        ASSERT_TRUE(std::isfinite(q[0]) && std::isfinite(q[1])) << "sample " << i << " row " << p / 2;
        diff += std::hypot(q[0] - f[0], q[1] - f[1]);
        norm += std::hypot(f[0], f[1]);
        ++rows;
      }
    }
    rel_diff = diff / norm;
    // Each row's parts (FEE over the slices, inertia, penetration) are that row's noise-free
    // force: the truth rows are matched to the sample's rows by stamp. Not to float rounding:
    // the kept force went through the sensor's base frame and back with the localised attitude
    // (0.09 % here), the parts straight from the map frame; a row's neighbour differs by ~36 %.
    ASSERT_EQ(ep.force_parts.size(), ep.samples.size());
    ASSERT_EQ(ep.truth_geometry_rows.size(), ep.samples.size());
    double part_diff = 0, cutting_rows = 0;
    for (std::size_t i = 0; i < ep.samples.size(); ++i) {
      ASSERT_EQ(ep.force_parts[i].size(), ep.force_quiet[i].size() * 3);
      for (std::size_t p = 0; p < ep.force_quiet[i].size() / 2; ++p) {
        const float* a = &ep.force_parts[i][p * 6];
        part_diff += std::hypot(a[0] + a[2] + a[4] - ep.force_quiet[i][p * 2], a[1] + a[3] + a[5] - ep.force_quiet[i][p * 2 + 1]);
        cutting_rows += std::isfinite(ep.truth_geometry_rows[i][p * 5 + 2]);
      }
    }
    EXPECT_LT(part_diff / norm, 0.01);
    EXPECT_GT(cutting_rows, rows / 2);
  };
  double quiet_diff = 1, noisy_diff = 0;
  long quiet_rows = 0, noisy_rows = 0;
  run((dir / "quiet.yaml").string(), quiet_diff, quiet_rows);
  run(src + "pinn_episode.yaml", noisy_diff, noisy_rows);
  EXPECT_GT(quiet_rows, 20);
  EXPECT_LT(quiet_diff, 1e-5) << "without noise the kept force is the measured one: " << quiet_diff;
  // The noise: the soil's 5 % + 150 N (coloured) and the sensor's 2 % + 100 N, per axis.
  EXPECT_GT(noisy_diff, 0.03) << noisy_diff;
  EXPECT_LT(noisy_diff, 0.3) << noisy_diff;
  fs::remove_all(dir);
}

// The dataset's pipeline file is as untrusted as any other: naming plugin folders is refused
// (loading a library runs its code) unless the embedder allowed it.
TEST(SoilDataset, APipelineFileMayNotChooseThePluginFolders) {
  const fs::path dir = fs::temp_directory_path() / ("terramap_soil_dataset_plugins_" + std::to_string(::getpid()));
  fs::create_directories(dir);
  const std::string src = std::string(TERRAMAP_SOURCE_DIR) + "/configs/dataset/";
  std::ifstream in(src + "pinn_pipeline.yaml");
  std::string yaml((std::istreambuf_iterator<char>(in)), std::istreambuf_iterator<char>());
  const auto at = yaml.find("threads: 1");
  ASSERT_NE(at, std::string::npos);
  yaml.insert(at, "plugin_paths: [" + dir.string() + "]\n");
  std::ofstream((dir / "pipeline.yaml").string()) << yaml;
  const std::string text = "version: 1\nseed: 5\nepisodes: 1\nduration_s: 1\nhistory: {T: 30, P: 10}\n"
                           "held_out: {episodes: 0, family: gravel, relative_density: [0.7, 1.0], rake_deg: 68}\n"
                           "scenario: " + src + "pinn_episode.yaml\npipeline: " + (dir / "pipeline.yaml").string() + "\n";
  const SoilDatasetConfig cfg = parseSoilDatasetConfig(text, "p.yaml", ".");
  try {
    runDatasetEpisode(cfg, planEpisode(cfg, 0), 1);
    ADD_FAILURE() << "the pipeline's plugin_paths were used";
  } catch (const ConfigError& e) {
    EXPECT_NE(std::string(e.what()).find("plugin_paths"), std::string::npos) << e.what();
  }
  fs::remove_all(dir);
}

TEST(SoilDataset, ReadingRefusesEpisodesOfAnotherConfiguration) {
  const fs::path dir = fs::temp_directory_path() / ("terramap_soil_dataset_mix_" + std::to_string(::getpid()));
  fs::create_directories(dir / "episodes");
  SoilDatasetConfig a = config(2, 0, 10), b = config(2, 0, 10, "relative_density: [0.2, 0.9]\n");
  EpisodeData ep;
  ep.plan = planEpisode(a, 0);
  writeEpisodeFile((dir / "episodes" / "ep_00000.h5").string(), a, ep);
  ep.plan = planEpisode(b, 1);
  writeEpisodeFile((dir / "episodes" / "ep_00001.h5").string(), b, ep);
  try {
    readSoilDataset(dir.string());
    FAIL() << "mixed configurations read";
  } catch (const InputError& e) {
    EXPECT_NE(std::string(e.what()).find("ep_00001.h5"), std::string::npos) << e.what();
  }
  fs::remove_all(dir);
}

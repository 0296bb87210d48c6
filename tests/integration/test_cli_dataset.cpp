// `terramap dataset` end to end: the same samples from 1 and 2 MPI ranks, resuming a killed run,
// refusing to mix configurations.
#include <terramap/eval/soil_dataset.hpp>

#include <gtest/gtest.h>

#include <cstdlib>

#include "cli_util.hpp"

using namespace terramap_test;

namespace {

// Two in-distribution episodes and one held-out, 5 s each (the first seconds cut ground the
// LiDAR has not yet seen, which gives no samples).
void writeConfig(const fs::path& dir) {
  const std::string src = std::string(TERRAMAP_SOURCE_DIR) + "/configs/dataset/";
  write(dir / "ds.yaml", "version: 1\nseed: 3\nepisodes: 2\nduration_s: 5\nhistory: {T: 20, P: 5}\n"
                         "held_out: {episodes: 1, family: gravel, relative_density: [0.7, 1.0], rake_deg: 68}\n"
                         "scenario: " + src + "pinn_episode.yaml\npipeline: " + src + "pinn_pipeline.yaml\n");
}

bool haveMpirun() { return std::system("command -v mpirun >/dev/null 2>&1") == 0; }

}  // namespace

TEST(CliDataset, SameSamplesForOneAndTwoMpiRanks) {
  if (!haveMpirun()) GTEST_SKIP() << "mpirun not installed (openmpi-bin)";
  const fs::path d = tempDir("dataset_mpi");
  writeConfig(d);
  // Running as root (CI containers) needs OpenMPI's explicit consent.
  const std::string mpirun = "OMPI_ALLOW_RUN_AS_ROOT=1 OMPI_ALLOW_RUN_AS_ROOT_CONFIRM=1 mpirun --oversubscribe -np ";
  const Result one = sh("dataset " + (d / "ds.yaml").string() + " --out " + (d / "one").string() + " -q", mpirun + "1 ");
  ASSERT_EQ(one.code, 0) << one.out;
  const Result two = sh("dataset " + (d / "ds.yaml").string() + " --out " + (d / "two").string() + " -q", mpirun + "2 ");
  ASSERT_EQ(two.code, 0) << two.out;
  EXPECT_NE(two.out.find("2 ranks"), std::string::npos) << two.out;
  const auto a = terramap::eval::readSoilDataset((d / "one").string());
  const auto b = terramap::eval::readSoilDataset((d / "two").string());
  ASSERT_GT(a.size(), 0u);
  EXPECT_EQ(a.obs, b.obs);
  EXPECT_EQ(a.theta_k, b.theta_k);
  EXPECT_EQ(a.force, b.force);
  EXPECT_EQ(a.truth, b.truth);
  EXPECT_EQ(a.split, b.split);
  fs::remove_all(d);
}

TEST(CliDataset, ResumesKeepingFinishedEpisodesAndRefusesAnotherConfig) {
  const fs::path d = tempDir("dataset_resume");
  writeConfig(d);
  const std::string cfg = (d / "ds.yaml").string(), out = (d / "out").string();
  const Result first = sh("dataset " + cfg + " --out " + out + " -q --threads 1");
  ASSERT_EQ(first.code, 0) << first.out;
  EXPECT_NE(first.out.find("3 episodes generated, 0 kept"), std::string::npos) << first.out;
  const std::string manifest = [&] { std::ifstream in(d / "out" / "manifest.json"); return std::string(std::istreambuf_iterator<char>(in), {}); }();
  EXPECT_NE(manifest.find("\"held_out\""), std::string::npos) << manifest;
  // A run killed after the first episode leaves only finished files (each written atomically):
  // the rerun makes the missing ones and keeps the rest.
  fs::remove(d / "out" / "episodes" / "ep_00001.h5");
  const auto before = fs::last_write_time(d / "out" / "episodes" / "ep_00000.h5");
  const Result again = sh("dataset " + cfg + " --out " + out + " -q --threads 1");
  ASSERT_EQ(again.code, 0) << again.out;
  EXPECT_NE(again.out.find("1 episodes generated, 2 kept"), std::string::npos) << again.out;
  EXPECT_EQ(fs::last_write_time(d / "out" / "episodes" / "ep_00000.h5"), before);
  // Another configuration into the same folder would mix two datasets: refused, exit code 3.
  write(d / "other.yaml", [&] { std::ifstream in(cfg); std::string s((std::istreambuf_iterator<char>(in)), {}); return s + "relative_density: [0.3, 0.9]\n"; }());
  const Result other = sh("dataset " + (d / "other.yaml").string() + " --out " + out + " -q");
  EXPECT_EQ(other.code, 3) << other.out;
  EXPECT_NE(other.out.find("another configuration"), std::string::npos) << other.out;
  fs::remove_all(d);
}

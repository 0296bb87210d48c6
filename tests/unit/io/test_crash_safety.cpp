// Crash safety of the writers: a child process rewrites a snapshot, a GeoTIFF
// or an episode over and over and is killed with SIGKILL at a random moment; the file under the
// target name must then always be a complete one (loads, checksum right, every value one
// version's), never a torn mix. 1,000 kills in all. The temporary files the killed writers
// leave are named `<target>.tmp.*` / `<target>.tmp-<pid>` and are never taken for the target.
#include <terramap/core/layered_map.hpp>
#include <terramap/io/geotiff.hpp>
#include <terramap/io/snapshot.hpp>
#include <terramap/sim/episode.hpp>
#include <terramap/sim/scenario.hpp>

#include <gdal_priv.h>
#include <gtest/gtest.h>

#include <signal.h>
#include <sys/wait.h>
#include <unistd.h>

#include <chrono>
#include <cstdlib>
#include <filesystem>
#include <functional>
#include <random>
#include <set>

#include "scratch_dir.hpp"

using namespace terramap;
namespace fs = std::filesystem;

namespace {

class CrashSafety : public ScratchDirTest {
 protected:
  CrashSafety() : ScratchDirTest("crash_") {}
};

LayeredMap mapOf(float v) {
  LayeredMap m(Geometry(0.1, Size(256, 256), Position(100.0, 200.0)));
  const LayerId id = m.addLayer("elevation", "m");
  m.fill(id, v);
  m.set(id, Index(3, 5), -v - 1.0f);  // not only a constant (and never equal to v): position matters too
  return m;
}

/// Forks a child that runs `write(version)` for versions 1, 2, 3, ... and reports each finished
/// write through a pipe; the parent waits for a random number (0-3) of finished writes, then a
/// random delay in [0, 1.5 x the time of one write] (timed here first), and kills it. Waiting on
/// the child's own progress rather than on the clock keeps kills before, during and after writes
/// however slowly a loaded machine runs the child. `check_target` runs after every kill.
void killDuringWrites(int kills, std::uint32_t seed, const std::function<void(int)>& write,
                      const std::function<void()>& check_target) {
  const auto t0 = std::chrono::steady_clock::now();
  write(0);
  const double once_us = std::chrono::duration<double, std::micro>(std::chrono::steady_clock::now() - t0).count();
  const int max_delay_us = std::max(100, static_cast<int>(1.5 * once_us));
  std::mt19937 rng(seed);
  std::uniform_int_distribution<int> delay(0, max_delay_us), finished(0, 3);
  for (int k = 0; k < kills; ++k) {
    int fds[2];
    ASSERT_EQ(pipe(fds), 0);
    const pid_t pid = fork();
    ASSERT_GE(pid, 0);
    if (pid == 0) {
      close(fds[0]);
      for (int v = 1;; ++v) {  // killed from outside
        write(v);
        const char done = 1;
        if (::write(fds[1], &done, 1) != 1) _exit(3);
      }
    }
    close(fds[1]);
    for (int j = finished(rng); j > 0; --j) {
      char c;
      if (read(fds[0], &c, 1) != 1) break;
    }
    usleep(static_cast<useconds_t>(delay(rng)));
    kill(pid, SIGKILL);
    int status = 0;
    waitpid(pid, &status, 0);
    close(fds[0]);
    ASSERT_TRUE(WIFSIGNALED(status) && WTERMSIG(status) == SIGKILL) << "writer did not die by SIGKILL";
    check_target();
    if (::testing::Test::HasFatalFailure() || ::testing::Test::HasFailure()) return;
  }
}

}  // namespace

TEST_F(CrashSafety, KilledSnapshotWritersLeaveTheLastCompleteFile) {
  const fs::path target = dir_ / "map.tmap";
  io::saveSnapshot(mapOf(0.0f), target);
  std::set<float> seen;
  killDuringWrites(
      450, 1, [&](int v) { io::saveSnapshot(mapOf(static_cast<float>(v)), target); },
      [&] {
        // loadSnapshot checks the length and checksums: a torn file throws.
        const LayeredMap m = io::loadSnapshot(target);
        const LayerId id = m.layerId("elevation");
        const float v = m.at(id, Index(0, 0));
        EXPECT_EQ(m.at(id, Index(255, 255)), v);
        EXPECT_EQ(m.at(id, Index(3, 5)), -v - 1.0f);
        seen.insert(v);
      });
  // The kills hit every phase: some writes completed between kills, some were cut short.
  EXPECT_GT(seen.size(), 2u);
}

TEST_F(CrashSafety, KilledGeoTiffWritersLeaveTheLastCompleteFile) {
  GDALAllRegister();
  const fs::path target = dir_ / "map.tif";
  io::writeGeoTiff(mapOf(0.0f), {"elevation"}, target);
  std::set<float> seen;
  killDuringWrites(
      450, 2, [&](int v) { io::writeGeoTiff(mapOf(static_cast<float>(v)), {"elevation"}, target); },
      [&] {
        const io::Raster r = io::readRaster(target);
        ASSERT_EQ(r.bands.size(), 1u);
        const Eigen::MatrixXf& b = r.bands[0].values;
        ASSERT_EQ(b.rows() * b.cols(), 256 * 256);
        // Every cell one version's (no mix of an old and a new half, no zeros of a short file):
        // all cells but the marked one equal, the marked one -v - 1.
        const float v = b(0, 0);
        long other = 0;
        for (Eigen::Index k = 0; k < b.size(); ++k) other += b.data()[k] != v;
        EXPECT_EQ(other, 1) << "torn raster";
        seen.insert(v);
      });
  EXPECT_GT(seen.size(), 2u);
}

TEST_F(CrashSafety, KilledEpisodeWritersLeaveTheLastCompleteFile) {
  const std::string yaml = R"(version: 1
name: tiny
duration_s: 0.2
threads: 1
terrain: {size_m: [4, 3], origin_m: [-1, -1.5], resolution_m: 0.02}
soil: {default: {family: loam, relative_density: 0.3}}
machines:
  - id: ctl1
    controller: {type: route, start_m: [0, 0], length_m: 2, passes: 1, depth_m: 0.02, speed_mps: 0.5}
)";
  sim::Scenario sc = sim::parseScenario(yaml, "tiny.yaml");
  const std::string out = (dir_ / "ep").string();
  const std::string path = sim::runEpisode(sc, out);
  std::vector<std::uint64_t> dims;
  sim::readEpisodeDataset(path, "/machines/ctl1/T_map_base", dims);
  ASSERT_EQ(dims.size(), 3u);
  const std::uint64_t obs = dims[0];  // observations of the 0.2 s run
  ASSERT_GT(obs, 5u);
  killDuringWrites(
      100, 3,
      [&](int v) {
        sim::Scenario s = sc;
        s.seed = static_cast<std::uint64_t>(v);
        sim::runEpisode(s, out);
      },
      [&] {
        // A complete episode: every dataset there with the run's length (a torn HDF5 file does
        // not open, a partial one lacks rows).
        std::vector<std::uint64_t> d;
        sim::readEpisodeDataset(path, "/machines/ctl1/T_map_base", d);
        ASSERT_EQ(d.size(), 3u);
        EXPECT_EQ(d[0], obs);
        EXPECT_FALSE(sim::readEpisodeDataset(path, "/terrain/snapshot_stamp", d).empty());
      });
}

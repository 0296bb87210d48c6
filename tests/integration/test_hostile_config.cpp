// Hostile and careless configurations and files, through the `terramap` binary:
// plugin folders named by a config file, plugin code run by `validate`, outputs beyond the
// memory budget, huge YAML files, duplicate keys, output folders that cannot be written, and
// temporary files left by killed or failed writers.
#include "cli_util.hpp"

#include <terramap/core/layered_map.hpp>
#include <terramap/io/snapshot.hpp>

#include <gtest/gtest.h>

#include <signal.h>
#include <sys/resource.h>
#include <sys/wait.h>
#include <unistd.h>

#include <chrono>
#include <string>
#include <vector>

using namespace terramap_test;

namespace {

const std::string kTestPlugins = std::string(TERRAMAP_BINARY_DIR) + "/test_plugins";
const std::string kScenario = std::string(TERRAMAP_SOURCE_DIR) + "/configs/scenarios/dense_strip.yaml";

/// A pipeline of one test_probe stage; `head` goes right after `version: 1`.
std::string probePipeline(const std::string& head, const std::string& type = "test_probe") {
  return "version: 1\n" + head + "map: {resolution: 0.5, size: [8, 8], tile: 8}\npipeline:\n  - {name: p, type: " +
         type + "}\nsource: {type: sequence, clouds: " + std::string(TERRAMAP_DATA_DIR) +
         "/gicp_pair, extensions: [.ply], max_frames: 1}\noutputs: {dir: out, png: [], snapshot: false, report: false}\n";
}

/// The short simulated run of the live view's test, writing into `out`.
std::string simPipeline(const std::string& outputs) {
  return "version: 1\nmap: {resolution: 0.2, size: [60, 40], center: [4, 0], tile: 32}\nthreads: 2\n"
         "source: {type: sim, scenario: " + kScenario + ", max_time_s: 0.5}\n"
         "pipeline:\n  - {name: lidar, type: lidar_fusion, params: {max_range_m: 30}}\n"
         "outputs: " + outputs + "\n";
}

/// A process id that is certainly not running: a child that has exited and been reaped.
long deadPid() {
  const pid_t p = fork();
  if (p == 0) _exit(0);
  waitpid(p, nullptr, 0);
  return p;
}

/// Runs the binary with a file-size limit (RLIMIT_FSIZE): a disk that fills up after `bytes`.
int runWithFileSizeLimit(const std::vector<std::string>& args, rlim_t bytes, std::string& out) {
  int fds[2];
  if (pipe(fds) != 0) return -1;
  const pid_t p = fork();
  if (p == 0) {
    dup2(fds[1], 1);
    dup2(fds[1], 2);
    close(fds[0]);
    setenv("TERRAMAP_PLUGIN_PATH", "", 1);
    signal(SIGXFSZ, SIG_IGN);  // a write past the limit fails with EFBIG, as ENOSPC would
    rlimit r{bytes, bytes};
    setrlimit(RLIMIT_FSIZE, &r);
    std::vector<std::string> a = args;
    a.insert(a.begin(), kBin);
    std::vector<char*> argv;
    for (auto& s : a) argv.push_back(s.data());
    argv.push_back(nullptr);
    execv(argv[0], argv.data());
    _exit(127);
  }
  close(fds[1]);
  char buf[4096];
  ssize_t n;
  while ((n = read(fds[0], buf, sizeof buf)) > 0) out.append(buf, static_cast<size_t>(n));
  close(fds[0]);
  int st = 0;
  waitpid(p, &st, 0);
  return WIFEXITED(st) ? WEXITSTATUS(st) : -1;
}

std::vector<std::string> temporaries(const fs::path& dir) {
  std::vector<std::string> out;
  for (const auto& e : fs::recursive_directory_iterator(dir))
    if (e.path().filename().string().find(".tmp") != std::string::npos) out.push_back(e.path().string());
  return out;
}

}  // namespace

// ---- (4) plugins named by a config file ------------------------------------------------------

TEST(HostileConfig, PluginFoldersFromAConfigFileAreRefusedUnlessAllowed) {
  const fs::path d = tempDir("cfg_plugin_paths");
  write(d / "p.yaml", probePipeline("plugin_paths: [" + kTestPlugins + "]\n"));
  const Result refused = sh("validate " + (d / "p.yaml").string());
  EXPECT_EQ(refused.code, 8) << refused.out;
  EXPECT_NE(refused.out.find("p.yaml:2:"), std::string::npos) << refused.out;
  EXPECT_NE(refused.out.find("--allow-config-plugin-paths"), std::string::npos) << refused.out;
  const Result run = sh("run " + (d / "p.yaml").string() + " -q");
  EXPECT_EQ(run.code, 3) << run.out;
  EXPECT_NE(run.out.find("--allow-config-plugin-paths"), std::string::npos) << run.out;
  // The user's own word: the switch, the command line or the environment.
  EXPECT_EQ(sh("validate " + (d / "p.yaml").string() + " --allow-config-plugin-paths").code, 0);
  write(d / "q.yaml", probePipeline(""));
  EXPECT_EQ(sh("validate " + (d / "q.yaml").string() + " --plugin-path " + kTestPlugins).code, 0);
  EXPECT_EQ(sh("validate " + (d / "q.yaml").string(), "TERRAMAP_PLUGIN_PATH=" + kTestPlugins + " ").code, 0);
}

TEST(HostileConfig, ValidateAndDidYouMeanRunNoCodeOfARefusedOrUnaskedLibrary) {
  const fs::path d = tempDir("cfg_no_code");
  fs::create_directories(d / "evil");
  fs::copy_file(kTestPlugins + "/marked_missing_symbol.so", d / "evil" / "evil.so");
  fs::copy_file(kTestPlugins + "/marked_probe.so", d / "evil" / "test_probe.so");
  const fs::path mark = d / "code_ran";
  const std::string env = "TERRAMAP_TEST_MARK_FILE=" + mark.string() + " ";
  // Not allowed: nothing in the folder is even opened.
  write(d / "a.yaml", probePipeline("plugin_paths: [evil]\n", "evil"));
  EXPECT_EQ(sh("validate " + (d / "a.yaml").string(), env).code, 8);
  EXPECT_FALSE(fs::exists(mark)) << "validate ran code from a folder the config file named";
  // Allowed, but the library does not export what a plugin must: refused from its symbol table.
  const Result missing = sh("validate " + (d / "a.yaml").string() + " --allow-config-plugin-paths", env);
  EXPECT_EQ(missing.code, 8) << missing.out;
  EXPECT_NE(missing.out.find("missing symbol 'terramap_plugin_create'"), std::string::npos) << missing.out;
  EXPECT_FALSE(fs::exists(mark)) << "the library's constructor ran before its refusal";
  // A mistyped type: the did-you-mean list comes from the files, nothing is loaded for it.
  write(d / "b.yaml", probePipeline("plugin_paths: [evil]\n", "test_prob"));
  const Result typo = sh("validate " + (d / "b.yaml").string() + " --allow-config-plugin-paths", env);
  EXPECT_EQ(typo.code, 8) << typo.out;
  EXPECT_NE(typo.out.find("did you mean 'test_probe'"), std::string::npos) << typo.out;
  EXPECT_FALSE(fs::exists(mark)) << "building the did-you-mean list loaded the libraries";
}

// ---- (5) the memory budget covers the outputs ------------------------------------------------

TEST(HostileConfig, OutputsOfASparseMapBeyondTheBudgetAreRefusedAtValidate) {
  const fs::path d = tempDir("cfg_out_budget");
  for (const std::string out : std::vector<std::string>{"{dir: out, geotiff: [elevation], png: [], snapshot: false}",
                                "{dir: out, geotiff: [], png: [elevation], snapshot: false}"}) {
    write(d / "p.yaml", "version: 1\nmap: {resolution: 0.05, size: [100000, 100000], sparse: true, tile: 64}\n"
                        "source: {type: sim, scenario: " + kScenario + ", max_time_s: 0.2}\n"
                        "pipeline:\n  - {name: lidar, type: lidar_fusion}\noutputs: " + out + "\n");
    const Result v = sh("--memory-budget 4G validate " + (d / "p.yaml").string());
    EXPECT_EQ(v.code, 8) << out << "\n" << v.out;
    EXPECT_NE(v.out.find("p.yaml:6:"), std::string::npos) << v.out;
    EXPECT_NE(v.out.find("memory budget"), std::string::npos) << v.out;
  }
}

TEST(HostileConfig, TheSimulatorsTruthPicturesAreInTheBudgetBeforeTheFirstEvent) {
  // `run` adds truth_elevation.png and elevation_error.png for a source that knows the truth,
  // with `png: []`: whole rasters of the sparse map, found out of budget only after the run.
  const fs::path d = tempDir("cfg_truth_budget");
  write(d / "p.yaml", "version: 1\nmap: {resolution: 0.05, size: [8000, 8000], sparse: true, tile: 64}\n"
                      "source: {type: sim, scenario: " + kScenario + ", max_time_s: 0.3}\n"
                      "pipeline:\n  - {name: lidar, type: lidar_fusion, params: {max_range_m: 30}}\n"
                      "outputs: {dir: out, geotiff: [], png: [], snapshot: false, report: false}\n");
  const auto t0 = std::chrono::steady_clock::now();
  const Result r = sh("--memory-budget 512M run " + (d / "p.yaml").string() + " -q");
  EXPECT_EQ(r.code, 3) << r.out;
  EXPECT_NE(r.out.find("truth pictures"), std::string::npos) << r.out;
  EXPECT_NE(r.out.find("memory budget"), std::string::npos) << r.out;
  EXPECT_LT(std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count(), 15.0);
}

TEST(HostileConfig, ExportOfAForgedSparseSnapshotIsAnInputErrorNotOutOfMemory) {
  const fs::path d = tempDir("cfg_forged_tmap");
  {
    terramap::MapOptions o;
    o.sparse = true;
    o.tile_size = 64;
    terramap::LayeredMap m(terramap::Geometry(0.05, terramap::Size(100000, 100000)), o);
    m.addLayer("elevation", "m");
    terramap::io::saveSnapshot(m, d / "forged.tmap");
  }
  ASSERT_LT(fs::file_size(d / "forged.tmap"), 4096u);
  for (const std::string fmt : std::vector<std::string>{"geotiff", "png"}) {
    const Result r = sh("--memory-budget 1G export " + (d / "forged.tmap").string() + " --layer elevation --format " +
                        fmt + " --out " + (d / ("x." + std::string(fmt == "png" ? "png" : "tif"))).string());
    EXPECT_EQ(r.code, 4) << fmt << ": " << r.out;
    EXPECT_NE(r.out.find("forged.tmap"), std::string::npos) << r.out;
    EXPECT_NE(r.out.find("memory budget"), std::string::npos) << r.out;
  }
  EXPECT_TRUE(temporaries(d).empty());
}

// ---- (6), (7) the YAML file itself -----------------------------------------------------------

TEST(HostileConfig, AYamlFileBeyondItsLimitIsRefusedBeforeParsing) {
  const fs::path d = tempDir("cfg_big_yaml");
  std::string pad = "# ";
  pad.append(1 << 20, 'x');
  write(d / "big.yaml", probePipeline("") + pad + "\n");
  const auto t0 = std::chrono::steady_clock::now();
  const std::string env = "TERRAMAP_PLUGIN_PATH=" + kTestPlugins + " ";
  const Result r = sh("--memory-budget 64M validate " + (d / "big.yaml").string(), env);
  EXPECT_EQ(r.code, 8) << r.out;
  EXPECT_NE(r.out.find("big.yaml"), std::string::npos) << r.out;
  EXPECT_NE(r.out.find("memory budget"), std::string::npos) << r.out;
  EXPECT_LT(std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count(), 10.0);
  // The same file under the default budget is fine: the limit follows the budget.
  EXPECT_EQ(sh("validate " + (d / "big.yaml").string(), env).code, 0);
}

TEST(HostileConfig, DuplicateKeysAreAnErrorNamingBothPlaces) {
  const fs::path d = tempDir("cfg_dup_keys");
  write(d / "top.yaml", probePipeline("") + "map: {resolution: 0.1, size: [8, 8]}\n");
  const std::string env = "TERRAMAP_PLUGIN_PATH=" + kTestPlugins + " ";
  const Result top = sh("validate " + (d / "top.yaml").string(), env);
  EXPECT_EQ(top.code, 8) << top.out;
  const std::string top_file = (d / "top.yaml").string();
  EXPECT_NE(top.out.find(top_file + ":7:1: map: key given twice (first at " + top_file + ":2:1)"), std::string::npos)
      << top.out;
  write(d / "nested.yaml", "version: 1\nmap: {resolution: 0.5, size: [8, 8], tile: 8, size: [4, 4]}\n"
                           "pipeline:\n  - {name: p, type: test_probe, params: {increment: 1,\n"
                           "     increment: 2}}\noutputs: {png: []}\n");
  const Result nested = sh("validate " + (d / "nested.yaml").string(), env);
  EXPECT_EQ(nested.code, 8) << nested.out;
  const std::string f = (d / "nested.yaml").string();
  EXPECT_NE(nested.out.find(f + ":2:47: map.size: key given twice (first at " + f + ":2:24)"), std::string::npos)
      << nested.out;
  EXPECT_NE(nested.out.find(f + ":5:6: pipeline[0].params.increment: key given twice (first at " + f + ":4:42)"),
            std::string::npos) << nested.out;
}

// ---- (8) the output folder is checked before the first event ---------------------------------

TEST(HostileConfig, AnOutputFolderThatCannotBeWrittenIsRefusedBeforeTheFirstEvent) {
  const fs::path d = tempDir("cfg_out_dir");
  write(d / "p.yaml", simPipeline("{dir: out, png: [elevation], snapshot: false}"));
  write(d / "a_file", "x");
  for (const fs::path out : std::vector<fs::path>{d / "a_file" / "sub", d / "a_file"}) {
    const Result r = sh("run " + (d / "p.yaml").string() + " -q --out " + out.string());
    EXPECT_EQ(r.code, 7) << r.out;
    EXPECT_NE(r.out.find(out.string()), std::string::npos) << r.out;
    EXPECT_NE(r.out.find("before the first event"), std::string::npos) << r.out;
  }
}

// ---- (9) temporary files ---------------------------------------------------------------------

TEST(HostileConfig, RunAndSimRemoveStaleTemporariesOfDeadProcessesOnly) {
  const fs::path d = tempDir("cfg_stale_tmp");
  const std::string dead = std::to_string(deadPid()), alive = std::to_string(getpid());
  for (const std::string cmd : std::vector<std::string>{"run", "sim"}) {
    const fs::path out = d / cmd;
    fs::create_directories(out / "sub");
    const std::vector<std::string> stale = {"map.tif.tmp." + dead + ".0123456789abcdef", "episode.h5.tmp-" + dead};
    const std::vector<std::string> kept = {"map.tif.tmp." + alive + ".0123456789abcdef", "episode.h5.tmp-" + alive,
                                           "notes.tmp-draft", "map.tif.tmp." + dead + ".xyz", "sub/episode.h5.tmp-" + dead};
    for (const auto& f : stale) write(out / f, std::string(1000, 'x'));
    for (const auto& f : kept) write(out / f, "keep");
    Result r;
    if (cmd == "run") {
      write(d / "p.yaml", simPipeline("{dir: out, png: [], snapshot: false, report: false}"));
      r = sh("run " + (d / "p.yaml").string() + " --out " + out.string());
    } else {
      r = sh("sim " + kScenario + " --duration 0.2 --no-clouds --out " + out.string());
    }
    ASSERT_EQ(r.code, 0) << r.out;
    for (const auto& f : stale) EXPECT_FALSE(fs::exists(out / f)) << cmd << ": " << f;
    for (const auto& f : kept) EXPECT_TRUE(fs::exists(out / f)) << cmd << ": " << f;
    EXPECT_NE(r.out.find("removed 2 stale temporary files of dead processes"), std::string::npos) << r.out;
  }
}

TEST(HostileConfig, WritersRemoveTheirTemporaryWhenTheDiskFills) {
  const fs::path d = tempDir("cfg_disk_full");
  write(d / "p.yaml", simPipeline("{dir: out, geotiff: [elevation], png: [elevation], snapshot: true}"));
  std::string out;
  int code = runWithFileSizeLimit({"run", (d / "p.yaml").string(), "-q", "--out", (d / "run").string()}, 20000, out);
  EXPECT_EQ(code, 7) << out;
  EXPECT_TRUE(temporaries(d / "run").empty()) << out;
  out.clear();
  code = runWithFileSizeLimit({"sim", kScenario, "--duration", "0.3", "--out", (d / "sim").string()}, 200000, out);
  EXPECT_EQ(code, 7) << out;
  EXPECT_TRUE(temporaries(d / "sim").empty()) << out;
}

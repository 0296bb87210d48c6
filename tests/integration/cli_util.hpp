#pragma once
// Running the `terramap` binary as a user does, for the end-to-end tests.
#include <sys/wait.h>
#include <unistd.h>

#include <array>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <string>

namespace terramap_test {
namespace fs = std::filesystem;

inline const std::string kBin = std::string(TERRAMAP_BINARY_DIR) + "/bin/terramap";

struct Result {
  int code = -1;
  std::string out;  // stdout + stderr
};
/// Runs `prefix terramap args` through the shell (prefix: e.g. an mpirun command line).
inline Result sh(const std::string& args, const std::string& prefix = "") {
  Result r;
  const std::string cmd = "TERRAMAP_PLUGIN_PATH= " + prefix + kBin + " " + args + " 2>&1";
  FILE* p = popen(cmd.c_str(), "r");
  std::array<char, 4096> buf{};
  size_t n;
  while ((n = fread(buf.data(), 1, buf.size(), p)) > 0) r.out.append(buf.data(), n);
  const int st = pclose(p);
  r.code = WIFEXITED(st) ? WEXITSTATUS(st) : -1;
  return r;
}
inline fs::path tempDir(const std::string& name) {
  const fs::path d = fs::temp_directory_path() / ("terramap_cli_" + name + "_" + std::to_string(getpid()));
  fs::remove_all(d);
  fs::create_directories(d);
  return d;
}
inline void write(const fs::path& p, const std::string& s) { std::ofstream(p) << s; }

}  // namespace terramap_test

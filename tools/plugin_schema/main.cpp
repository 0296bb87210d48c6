// terramap-plugin-schema: embeds a plugin's description (parameters, layers as a function of
// them; plugin_schema.hpp) into the plugin module itself, so `terramap validate` can check a
// pipeline without loading the plugin. Run by terramap_add_plugin() right after the module is
// linked: building already trusts the plugin's code, so loading it here adds no trust; the host
// that validates a pipeline never loads it.
//
//   terramap-plugin-schema [--objcopy PATH] [--set KEY=VALUE]... PLUGIN.so   embed (in place)
//   terramap-plugin-schema --print [--set KEY=VALUE]... PLUGIN.so              print the JSON
#include <terramap/pipeline/plugin_schema.hpp>

#include "../../engine/pipeline/elf_section.hpp"

#include <sys/wait.h>
#include <unistd.h>

#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <iostream>
#include <string>
#include <vector>

namespace fs = std::filesystem;

namespace {

int usage() {
  std::cerr << "usage: terramap-plugin-schema [--objcopy PATH | --print] [--set KEY=VALUE]... PLUGIN.so\n";
  return 2;
}

/// Runs argv[0] with argv (no shell); its exit status, or -1.
int runProgram(const std::vector<std::string>& args) {
  std::vector<char*> argv;
  for (const auto& a : args) argv.push_back(const_cast<char*>(a.c_str()));
  argv.push_back(nullptr);
  const pid_t pid = fork();
  if (pid < 0) return -1;
  if (pid == 0) {
    execvp(argv[0], argv.data());
    _exit(127);
  }
  int status = 0;
  if (waitpid(pid, &status, 0) != pid) return -1;
  return WIFEXITED(status) ? WEXITSTATUS(status) : -1;
}

int describeAndEmbed(int argc, char** argv);

}  // namespace

// Ends with _Exit, after flushing: the loaded plugin and what it pulls in (PCL's OpenNI2 through
// terramap::io) are never torn down. Their static destructors are none of the build's business,
// and OpenNI2's unlock a destroyed mutex at exit, which fails the build under ThreadSanitizer
// although the description was written.
int main(int argc, char** argv) {
  const int rc = describeAndEmbed(argc, argv);
  std::cout.flush();
  std::fflush(nullptr);
  std::_Exit(rc);
}

namespace {

int describeAndEmbed(int argc, char** argv) {
  std::string objcopy = "objcopy", plugin;
  std::vector<std::string> probe;
  bool print = false;
  for (int i = 1; i < argc; ++i) {
    const std::string a = argv[i];
    if (a == "--objcopy" && i + 1 < argc) objcopy = argv[++i];
    else if (a == "--set" && i + 1 < argc) probe.emplace_back(argv[++i]);
    else if (a == "--print") print = true;
    else if (!a.empty() && a[0] != '-' && plugin.empty()) plugin = a;
    else return usage();
  }
  if (plugin.empty()) return usage();
  try {
    const terramap::PluginDescription d = terramap::describePlugin(plugin, probe);
    const std::string json = terramap::descriptionToJson(d);
    if (print) {
      std::cout << json << "\n";
      return 0;
    }
    // objcopy writes a new file beside the plugin, renamed over it only once complete: an
    // interrupted build never leaves a half-written module.
    const std::string pid = std::to_string(getpid());
    const fs::path json_file = plugin + ".schema.tmp-" + pid, out = plugin + ".tmp-" + pid;
    {
      std::ofstream f(json_file, std::ios::binary);
      f << json;
      if (!f.flush()) throw terramap::OutputError(json_file.string() + ": cannot write");
    }
    const int rc = runProgram({objcopy, "--remove-section", TERRAMAP_PLUGIN_SCHEMA_SECTION, "--add-section",
                               std::string(TERRAMAP_PLUGIN_SCHEMA_SECTION) + "=" + json_file.string(), plugin,
                               out.string()});
    std::error_code ec;
    fs::remove(json_file, ec);
    if (rc != 0) {
      fs::remove(out, ec);
      throw terramap::OutputError(plugin + ": " + objcopy + " failed (exit " + std::to_string(rc) + ")");
    }
    // What the host will read back: the same text, and the build-id it is bound to unchanged.
    const auto back = terramap::detail::readElfSection(out.string(), TERRAMAP_PLUGIN_SCHEMA_SECTION, json.size() + 1);
    if (!back || *back != json || terramap::elfBuildId(out.string()) != d.build_id) {
      fs::remove(out, ec);
      throw terramap::OutputError(plugin + ": the embedded schema does not read back as written");
    }
    fs::rename(out, plugin);
    std::cout << "terramap-plugin-schema: " << plugin << ": " << d.params.size() << " parameters, "
              << d.layers.size() << " layers" << (d.layers_vary_with.empty() ? "" : ", layers vary with [")
              << [&] {
                   std::string s;
                   for (const auto& p : d.layers_vary_with) s += (s.empty() ? "" : ", ") + p;
                   return d.layers_vary_with.empty() ? s : s + "]";
                 }()
              << "\n";
    return 0;
  } catch (const std::exception& e) {
    std::cerr << "terramap-plugin-schema: " << e.what() << "\n";
    return 1;
  }
}

}  // namespace

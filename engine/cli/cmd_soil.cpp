// `terramap dataset|train|eval-soil ...`: the soil estimator's commands live in the sibling
// program terramap-soil (it links MPI and libtorch; this one stays light). They are listed here
// so `terramap --help` shows them, and exec terramap-soil with the same arguments, which also
// works under `mpirun -np N terramap dataset ...` (exec keeps the MPI launcher's environment).
#include "command.hpp"

#include <unistd.h>

#include <cerrno>
#include <cstring>
#include <filesystem>

namespace terramap::cli {
namespace {

int execSoilTool(const std::string& command, const std::vector<std::string>& rest) {
  namespace fs = std::filesystem;
  std::error_code ec;
  const fs::path self = fs::read_symlink("/proc/self/exe", ec);
  const fs::path tool = (ec ? fs::path(".") : self.parent_path()) / "terramap-soil";
  std::vector<std::string> args{tool.string(), command};
  args.insert(args.end(), rest.begin(), rest.end());
  std::vector<char*> argv;
  for (auto& s : args) argv.push_back(s.data());
  argv.push_back(nullptr);
  ::execv(tool.c_str(), argv.data());
  throw Error("cannot run " + tool.string() + " (" + std::strerror(errno) +
              "): `terramap " + command + "` needs the terramap-soil program installed beside terramap");
}

void addForwarded(CLI::App& app, std::function<int()>& run, const std::string& name, const std::string& help) {
  CLI::App* sub = app.add_subcommand(name, help + " (terramap-soil " + name + " --help)");
  sub->prefix_command();
  sub->allow_extras();
  sub->fallthrough(false);
  sub->set_help_flag();  // --help goes to terramap-soil, which knows the options
  sub->callback([&run, sub, name] {
    run = [rest = sub->remaining(), name] { return execSoilTool(name, rest); };
  });
}

Registrar reg_dataset{Command{"dataset", [](CLI::App& app, std::function<int()>& run) {
  addForwarded(app, run, "dataset", "Generate the soil estimator's training episodes (MPI ranks via mpirun)");
}}};
Registrar reg_eval_soil{Command{"eval-soil", [](CLI::App& app, std::function<int()>& run) {
  addForwarded(app, run, "eval-soil", "Evaluate the soil estimator against the simulator's truth");
}}};
Registrar reg_train{Command{"train", [](CLI::App& app, std::function<int()>& run) {
  addForwarded(app, run, "train", "Train the soil estimator's ensemble (libtorch)");
}}};

}  // namespace
}  // namespace terramap::cli

// terramap-soil: the soil estimator's dataset, training and evaluation commands. Users run it
// through `terramap dataset|train|eval-soil`, which exec this program with the same arguments.
#include "command.hpp"

#include <terramap/eval/sim_source.hpp>

#include <algorithm>

namespace terramap::cli {
std::vector<Command>& registry() {
  static std::vector<Command> r;
  return r;
}
}  // namespace terramap::cli

int main(int argc, char** argv) {
  using namespace terramap::cli;
  terramap::sim::registerSimSource();
  CLI::App app{"terramap-soil: the soil estimator's dataset, training and evaluation (run as `terramap <command>`)"};
  app.require_subcommand(1);
  std::function<int()> run;
  auto& cmds = registry();
  std::sort(cmds.begin(), cmds.end(), [](const Command& a, const Command& b) { return a.name < b.name; });
  for (auto& c : cmds) c.setup(app, run);
  try {
    app.parse(argc, argv);
  } catch (const CLI::ParseError& e) {
    const int rc = app.exit(e);
    return rc == 0 ? kOk : kUsage;
  }
  return runMapped("terramap", [&] { return run ? run() : kUsage; });
}

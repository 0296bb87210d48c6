// terramap-soil: the soil estimator's dataset, training and evaluation commands. Users run it
// through `terramap dataset|train|eval-soil`, which exec this program with the same arguments.
#include "command.hpp"

#include <terramap/eval/sim_source.hpp>

int main(int argc, char** argv) {
  using namespace terramap::cli;
  terramap::sim::registerSimSource();
  CLI::App app{"terramap-soil: the soil estimator's dataset, training and evaluation (run as `terramap <command>`)"};
  app.require_subcommand(1);
  return runApp(app, argc, argv, "terramap", [] {});
}

// `terramap sim SCENARIO.yaml --out DIR`: run a simulated episode into DIR/episode.h5.
#include "command.hpp"

#include <terramap/sim/episode.hpp>
#include <terramap/sim/scenario.hpp>

#include <chrono>
#include <iostream>

namespace terramap::cli {
namespace {

struct SimArgs {
  std::string scenario, out;
  double duration = -1;
  long long seed = -1;
  int threads = 0;
  bool no_clouds = false;
};

Registrar reg{Command{"sim", [](CLI::App& app, std::function<int()>& run) {
  auto args = std::make_shared<SimArgs>();
  CLI::App* sub = app.add_subcommand("sim", "Run a simulator scenario and write an HDF5 episode (docs/sim.md)");
  sub->add_option("scenario", args->scenario, "scenario YAML (see configs/scenarios/)")->required();
  sub->add_option("--out", args->out, "output folder (episode.h5 is written there)")->required();
  sub->add_option("--duration", args->duration, "override duration_s");
  sub->add_option("--seed", args->seed, "override the scenario seed");
  sub->add_option("--threads", args->threads, "override LiDAR ray-casting threads (results do not depend on it)");
  sub->add_flag("--no-clouds", args->no_clouds, "do not store LiDAR clouds");
  sub->callback([args, &run] {
    run = [args]() {
      sim::Scenario sc = sim::loadScenario(args->scenario);
      if (args->duration > 0) sc.duration_s = args->duration;
      if (args->seed >= 0) sc.seed = static_cast<std::uint64_t>(args->seed);
      if (args->threads > 0) sc.threads = args->threads;
      sim::EpisodeOptions opt;
      opt.clouds = !args->no_clouds;
      const auto t0 = std::chrono::steady_clock::now();
      const std::string path = sim::runEpisode(sc, args->out, opt);
      const double wall = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
      std::cout << "wrote " << path << ": " << sc.duration_s << " s simulated in " << wall << " s wall ("
                << sc.duration_s / wall << "x real time)\n";
      return kOk;
    };
  });
}}};

}  // namespace
}  // namespace terramap::cli

// `terramap sim SCENARIO.yaml --out DIR`: run a simulated episode into DIR/episode.h5.
#include "command.hpp"

#include <terramap/io/atomic_file.hpp>
#include <terramap/sim/command_log.hpp>
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
  int cloud_compression = 0;
  std::string export_commands, export_tum;
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
  sub->add_option("--cloud-compression", args->cloud_compression,
                  "gzip level 0-9 for the stored LiDAR clouds (default 0: about 74 % of the size for more CPU than the simulation)")
      ->check(CLI::Range(0, 9));
  sub->add_option("--export-commands", args->export_commands,
                  "also write the first machine's commands as a replay CSV (units: si; docs/sim.md \"Replaying commands\")");
  sub->add_option("--export-tum", args->export_tum, "also write the first machine's truth base trajectory as a TUM file");
  sub->callback([args, &run] {
    run = [args]() {
      sim::Scenario sc = sim::loadScenario(args->scenario);
      if (args->duration > 0) sc.duration_s = args->duration;
      if (args->seed >= 0) sc.seed = static_cast<std::uint64_t>(args->seed);
      if (args->threads > 0) sc.threads = args->threads;
      sim::EpisodeOptions opt;
      opt.clouds = !args->no_clouds;
      opt.cloud_compression = args->cloud_compression;
      sim::EpisodeTiming tm;
      // Refused before simulating, not after; a killed run's temporaries are swept first.
      io::requireWritableFolder(args->out);
      const auto stale = io::removeStaleTemporaries(args->out);
      if (!stale.empty()) {
        std::string names;
        for (const auto& p : stale) names += (names.empty() ? "" : ", ") + p.string();
        std::cout << "removed " << stale.size() << " stale temporary file" << (stale.size() == 1 ? "" : "s")
                  << " of dead processes from " << args->out << ": " << names << "\n";
      }
      // A failed episode (a full disk) removes its temporary itself (sim::EpisodeWriter).
      const std::string path = sim::runEpisode(sc, args->out, opt, &tm);
      // The run's rate is the figure to compare with BM_SimRealtime (which builds its world
      // outside the timed loop); the set-up is a fixed cost per episode, said on its own.
      std::cout << "wrote " << path << ": " << sc.duration_s << " s simulated in " << tm.run_s << " s wall ("
                << sc.duration_s / tm.run_s << "x real time), after " << tm.setup_s
                << " s building the world and laying out the file (" << sc.duration_s / (tm.setup_s + tm.run_s)
                << "x real time with it); the writer thread used " << tm.writer_cpu_s
                << " s of CPU beside the simulation, closing the file (last writes, checksum, flush to disk) "
                << tm.close_s << " s of the run (last writes " << tm.close_parts.writes_s << " s, HDF5 close "
                << tm.close_parts.hdf5_s << " s, checksum and flush " << tm.close_parts.seal_s << " s)\n";
      // A still sensor re-casts only the rays over changed terrain: say how much that was.
      if (tm.rays > 0)
        std::cout << tm.rays << " rays cast or kept, " << tm.rays_kept
                  << " of them kept from their sensor's previous scan (it had not moved and the terrain under them "
                     "had not changed; docs/sim.md \"Kept hits\")\n";
      if (!args->export_commands.empty()) {
        sim::writeCommandLog(args->export_commands, sim::episodeCommands(path, sc.machines.front().id));
        std::cout << "wrote " << args->export_commands << "\n";
      }
      if (!args->export_tum.empty()) {
        const std::string& id = sc.machines.front().id;
        io::writeTumTrajectory(args->export_tum, sim::episodeTrajectory(sim::EpisodeFile(path), id),
                               id + " truth base trajectory from " + path + ": stamp tx ty tz qx qy qz qw");
        std::cout << "wrote " << args->export_tum << "\n";
      }
      return kOk;
    };
  });
}}};

}  // namespace
}  // namespace terramap::cli

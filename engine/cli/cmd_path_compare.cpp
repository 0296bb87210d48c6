// `terramap path-compare PATH REFERENCE`: a machine's path against a reference path (TERA's
// real-versus-simulated comparison; docs/sim.md "Replaying commands").
#include "command.hpp"

#include <terramap/io/atomic_file.hpp>
#include <terramap/io/trajectory.hpp>
#include <terramap/sim/episode.hpp>

#include <nlohmann/json.hpp>

#include <cstdio>
#include <iostream>
#include <memory>
#include <string>

namespace terramap::cli {
namespace {

struct PathCompareArgs {
  std::string path, reference, machine = "ctl1", reference_machine, align = "none", json;
};

bool isEpisode(const std::string& file) {
  return file.size() > 3 && file.compare(file.size() - 3, 3, ".h5") == 0;
}

/// A TUM file, or an episode's truth base trajectory of `machine`.
io::Trajectory load(const std::string& file, const std::string& machine) {
  if (!isEpisode(file)) return io::readTumTrajectory(file);
  return sim::episodeTrajectory(sim::EpisodeFile(file), machine);
}

Registrar reg{Command{"path-compare", [](CLI::App& app, std::function<int()>& run) {
  auto a = std::make_shared<PathCompareArgs>();
  CLI::App* sub = app.add_subcommand(
      "path-compare",
      "A machine's path against a reference path: lengths and position errors (TUM files or episode.h5 truth)");
  sub->add_option("path", a->path, "TUM file (stamp tx ty tz qx qy qz qw) or an episode.h5")->required();
  sub->add_option("reference", a->reference, "TUM file or episode.h5 to compare against")->required();
  sub->add_option("--machine", a->machine, "machine id in an episode PATH")->capture_default_str();
  sub->add_option("--reference-machine", a->reference_machine, "machine id in an episode REFERENCE (default: --machine)");
  sub->add_option("--align", a->align, "none, se2 (rotation about z + xy shift) or se3: least-squares rigid fit first")
      ->capture_default_str();
  sub->add_option("--json", a->json, "also write the figures as JSON to this file");
  sub->callback([a, &run] {
    run = [a]() {
      const io::PathAlignment align = io::parsePathAlignment(a->align, "--align");
      const io::Trajectory path = load(a->path, a->machine);
      const io::Trajectory ref = load(a->reference, a->reference_machine.empty() ? a->machine : a->reference_machine);
      const io::PathComparison c = io::comparePaths(path, ref, align);
      char line[512];
      std::snprintf(line, sizeof line,
                    "%zu poses over %.3f-%.3f s: path %.3f m, reference %.3f m; position error (align %s) RMSE %.4f m "
                    "(horizontal %.4f m), mean %.4f m, max %.4f m, final %.4f m\n",
                    c.pairs, c.start_stamp, c.end_stamp, c.length_m, c.reference_length_m, a->align.c_str(), c.rmse_m,
                    c.rmse_xy_m, c.mean_m, c.max_m, c.final_m);
      std::cout << line;
      if (!a->json.empty()) {
        nlohmann::json j{{"path", a->path},         {"reference", a->reference},   {"align", a->align},
                         {"pairs", c.pairs},        {"start_stamp", c.start_stamp}, {"end_stamp", c.end_stamp},
                         {"length_m", c.length_m},  {"reference_length_m", c.reference_length_m},
                         {"rmse_m", c.rmse_m},      {"rmse_xy_m", c.rmse_xy_m},    {"mean_m", c.mean_m},
                         {"max_m", c.max_m},        {"final_m", c.final_m}};
        io::writeFileAtomically(a->json, j.dump(2) + "\n");
      }
      return kOk;
    };
  });
}}};

}  // namespace
}  // namespace terramap::cli

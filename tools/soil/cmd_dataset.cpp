// `terramap dataset CONFIG --out DIR`: the soil estimator's training episodes, one HDF5 file each.
// Under `mpirun -np N` every rank runs the episodes i with i % N == rank; an episode's content
// depends only on (config, i), so the files are the same bits for any N. Existing episode files
// are kept (a killed run resumes); `--force` regenerates them.
#include "command.hpp"

#include <terramap/core/error.hpp>
#include <terramap/eval/soil_dataset.hpp>
#include <terramap/io/atomic_file.hpp>

#include <mpi.h>
#include <unistd.h>

#include <chrono>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <sstream>
#include <thread>

namespace terramap::cli {
namespace {
namespace fs = std::filesystem;

struct DatasetArgs {
  std::string config, out;
  int episodes = -1, held_out = -1, threads = 0;
  bool force = false, quiet = false;
};

// MPI for the lifetime of the command; a singleton (not under mpirun) is one rank.
struct MpiSession {
  int rank = 0, size = 1;
  MpiSession() {
    int inited = 0;
    MPI_Initialized(&inited);
    if (!inited) MPI_Init(nullptr, nullptr);
    MPI_Comm_rank(MPI_COMM_WORLD, &rank);
    MPI_Comm_size(MPI_COMM_WORLD, &size);
  }
  ~MpiSession() {
    int finalized = 0;
    MPI_Finalized(&finalized);
    if (!finalized) MPI_Finalize();
  }
};

std::string readText(const fs::path& p) {
  std::ifstream in(p, std::ios::binary);
  std::ostringstream os;
  os << in.rdbuf();
  return os.str();
}

int runDataset(const DatasetArgs& a) {
  MpiSession mpi;
  eval::SoilDatasetConfig cfg = eval::loadSoilDatasetConfig(a.config);
  if (a.episodes >= 0) cfg.episodes = a.episodes;
  if (a.held_out >= 0) cfg.held_out_episodes = a.held_out;
  const fs::path out(a.out);
  const fs::path ep_dir = out / "episodes";
  std::error_code ec;
  fs::create_directories(ep_dir, ec);
  if (ec) throw OutputError(ep_dir.string() + ": cannot create the output folder: " + ec.message());
  // One folder holds one configuration: episodes of another config would mix silently.
  const fs::path cfg_copy = out / "config.yaml";
  if (fs::exists(cfg_copy) && readText(cfg_copy) != cfg.yaml_text && !a.force)
    throw ConfigError(out.string() + " holds a dataset of another configuration (" + cfg_copy.string() +
                      " differs from " + a.config + "): use another --out, or --force to regenerate every episode");
  MPI_Barrier(MPI_COMM_WORLD);  // every rank compared before rank 0 replaces the copy
  if (mpi.rank == 0) io::writeFileAtomically(cfg_copy, cfg.yaml_text);

  const int threads = a.threads > 0
      ? a.threads
      : std::max(1, static_cast<int>(std::thread::hardware_concurrency()) / mpi.size);
  const int total = eval::episodeCount(cfg);
  std::vector<int> mine;
  for (int i = mpi.rank; i < total; i += mpi.size) mine.push_back(i);
  long done = 0, kept = 0, samples = 0;
  double simulated = 0;
  const auto t0 = std::chrono::steady_clock::now();
  const bool tty = !a.quiet && isatty(fileno(stderr)) && mpi.size == 1;
  std::string failure;
  try {
    for (std::size_t k = 0; k < mine.size(); ++k) {
      const int i = mine[k];
      const eval::EpisodePlan plan = eval::planEpisode(cfg, i);
      const fs::path path = ep_dir / eval::episodeFileName(plan);
      if (!a.force && fs::exists(path)) {
        ++kept;
        continue;
      }
      auto progress = [&](double t, double d) {
        if (!tty) return;
        const double frac = (static_cast<double>(k) + (d > 0 ? t / d : 0)) / static_cast<double>(mine.size());
        const int width = 30, filled = static_cast<int>(frac * width);
        std::fprintf(stderr, "\r  [%s%s] %5.1f%%  episode %d/%d", std::string(filled, '#').c_str(),
                     std::string(width - filled, '.').c_str(), 100 * frac, i + 1, total);
        std::fflush(stderr);
      };
      const eval::EpisodeData ep = eval::runDatasetEpisode(cfg, plan, threads, progress);
      eval::writeEpisodeFile(path.string(), cfg, ep);
      ++done;
      samples += static_cast<long>(ep.samples.size());
      simulated += ep.simulated_s;
      if (!a.quiet && !tty)
        std::fprintf(stderr, "[rank %d/%d] episode %d (%s, %s, I_d %.2f, rake %.1f deg): %zu samples of %ld sweeps, %.1f s\n",
                     mpi.rank, mpi.size, i, eval::datasetSplitName(plan.split), soil::soilFamilyName(plan.family),
                     plan.relative_density, plan.rake_rad * 180 / 3.14159265358979323846, ep.samples.size(), ep.sweeps,
                     ep.wall_s);
    }
  } catch (const std::exception& e) {
    failure = e.what();
  }
  if (tty) std::fprintf(stderr, "\r%60s\r", "");
  const double wall = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
  // Every rank reaches the reduction, failed or not, so a failure cannot leave the others waiting.
  long local[3] = {done, kept, samples}, sum[3] = {0, 0, 0};
  int failed = failure.empty() ? 0 : 1, any_failed = 0;
  double wall_max = 0, sim_sum = 0;
  MPI_Reduce(local, sum, 3, MPI_LONG, MPI_SUM, 0, MPI_COMM_WORLD);
  MPI_Reduce(&wall, &wall_max, 1, MPI_DOUBLE, MPI_MAX, 0, MPI_COMM_WORLD);
  MPI_Reduce(&simulated, &sim_sum, 1, MPI_DOUBLE, MPI_SUM, 0, MPI_COMM_WORLD);
  MPI_Allreduce(&failed, &any_failed, 1, MPI_INT, MPI_MAX, MPI_COMM_WORLD);
  if (failed) throw Error("rank " + std::to_string(mpi.rank) + ": " + failure);
  if (any_failed) return kInternal;  // the failing rank printed why
  if (mpi.rank == 0) {
    io::writeFileAtomically(out / "manifest.json", eval::datasetManifestJson(out.string()) + "\n");
    std::printf("dataset %s: %ld episodes generated, %ld kept from an earlier run, %ld new samples; %d rank%s x %d "
                "thread%s, %.1f s wall (%.1f simulated s per wall s)\n",
                out.string().c_str(), sum[0], sum[1], sum[2], mpi.size, mpi.size == 1 ? "" : "s", threads,
                threads == 1 ? "" : "s", wall_max, wall_max > 0 ? sim_sum / wall_max : 0.0);
    std::printf("wrote %s\n", (out / "manifest.json").string().c_str());
  }
  return kOk;
}

Registrar reg{Command{"dataset", [](CLI::App& app, std::function<int()>& run) {
  auto a = std::make_shared<DatasetArgs>();
  CLI::App* sub = app.add_subcommand(
      "dataset",
      "Generate the soil estimator's training episodes (configs/dataset/pinn.yaml); run under\n"
      "`mpirun -np N` to split the episodes over N ranks (same files for any N). Resumes: episode\n"
      "files that exist are kept.");
  sub->add_option("config", a->config, "dataset configuration YAML")->required();
  sub->add_option("--out", a->out, "output folder (episodes/ep_NNNNN.h5, manifest.json, config.yaml)")->required();
  sub->add_option("--episodes", a->episodes, "override the number of in-distribution episodes");
  sub->add_option("--held-out-episodes", a->held_out, "override the number of held-out episodes");
  sub->add_option("--threads", a->threads,
                  "threads per rank for the simulator and the pipeline (default: cores / ranks; results do not depend on it)");
  sub->add_flag("--force", a->force, "regenerate episode files that already exist");
  sub->add_flag("--quiet,-q", a->quiet, "no per-episode lines");
  sub->callback([&run, a] { run = [a] { return runDataset(*a); }; });
}}};

}  // namespace
}  // namespace terramap::cli

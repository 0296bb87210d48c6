#pragma once
/// \file
/// Writing a simulated episode to HDF5 (layout in docs/sim.md, readable with h5py).
/// The file is written to "<path>.tmp-<pid>" in the same folder and renamed over <path> by
/// close(), so a crash never leaves a half-written episode under the final name.
#include <terramap/core/events.hpp>
#include <terramap/sim/simulator.hpp>

#include <cstdint>
#include <memory>
#include <string>
#include <vector>

namespace terramap::sim {

struct EpisodeOptions {
  bool clouds = true;          ///< store LiDAR clouds (the bulk of the file)
  int compression = 1;         ///< gzip level for the terrain and cloud datasets (0 = none)
};

class EpisodeWriter {
 public:
  /// Opens the temporary file and writes the static parts (scenario text, initial terrain,
  /// surface soil maps). \throws OutputError naming the path.
  EpisodeWriter(const std::string& path, const Simulator& sim, EpisodeOptions options = {});
  /// Removes the temporary file if close() was not called.
  ~EpisodeWriter();
  EpisodeWriter(const EpisodeWriter&) = delete;
  EpisodeWriter& operator=(const EpisodeWriter&) = delete;

  /// Records one next() worth of events plus the simulator's truth after it (call after
  /// every successful next()). Writes a terrain snapshot when its interval has elapsed.
  /// \throws OutputError
  void record(const Simulator& sim, const std::vector<Event>& events);
  /// Writes the final terrain snapshot, flushes, closes, seals (io/file_seal.hpp) and renames
  /// into place.
  void close(const Simulator& sim);

  struct Impl;

 private:
  std::unique_ptr<Impl> impl_;
};

/// Reads one numeric dataset of an episode (any numeric type, converted to double) with its
/// dimensions; e.g. "/machines/ctl1/force_base_N". For evaluation tools and tests; the layout is
/// plain HDF5 behind a 512-byte user block, so h5py or the HDF5 C API read it as well. The file's
/// seal is verified first (io::verifySeal): a truncated or damaged file is an InputError and never
/// reaches libhdf5. \throws InputError naming file and dataset.
std::vector<double> readEpisodeDataset(const std::string& path, const std::string& dataset,
                                       std::vector<std::uint64_t>& dims);

/// Runs a whole scenario into `dir`/episode.h5 (creating `dir`). Returns the file path.
std::string runEpisode(const Scenario& scenario, const std::string& dir, EpisodeOptions options = {});

}  // namespace terramap::sim

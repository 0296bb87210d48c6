#pragma once
/// \file
/// Writing a simulated episode to HDF5 (layout in docs/sim.md, readable with h5py).
/// The file is written to "<path>.tmp-<pid>" in the same folder and renamed over <path> by
/// close(), so a crash never leaves a half-written episode under the final name.
#include <terramap/core/events.hpp>
#include <terramap/io/trajectory.hpp>
#include <terramap/sim/simulator.hpp>

#include <cstdint>
#include <memory>
#include <string>
#include <vector>

namespace terramap::sim {

struct EpisodeOptions {
  bool clouds = true;          ///< store LiDAR clouds (the bulk of the file)
  int compression = 1;         ///< gzip level for the terrain grids and snapshots (0 = none)
  /// gzip level for the LiDAR clouds (0 = none, the default: deflate shrinks float point clouds
  /// only to about 74 % and costs more CPU than simulating them; `terramap sim --cloud-compression 1`).
  int cloud_compression = 0;
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
  /// The same, taking the point clouds' buffers instead of copying them (they are most of an
  /// episode's bytes); `events` is left valid but its clouds' points unspecified (clear() it).
  void record(const Simulator& sim, std::vector<Event>&& events);
  /// Writes the final terrain snapshot, flushes, closes, seals (io/file_seal.hpp) and renames
  /// into place.
  void close(const Simulator& sim);
  /// CPU seconds the writer thread used (deflating snapshot chunks, HDF5 writes, the kernel's
  /// copies); 0 before close(). The simulation's cores pay for it: `terramap sim` prints it.
  double writerCpuSeconds() const;
  /// close()'s parts (wall s; 0 before close()): the last writes (the final snapshot and
  /// buffered rows, while the writer thread drains), the HDF5 close, the seal (checksum, flush
  /// to disk, rename).
  struct CloseTiming {
    double writes_s = 0, hdf5_s = 0, seal_s = 0;
  };
  CloseTiming closeTiming() const;

  struct Impl;

 private:
  std::unique_ptr<Impl> impl_;
};

/// A sealed terramap HDF5 file (simulator or soil-dataset episode) opened for reading: the seal
/// is verified once (io::verifySeal: a truncated or damaged file is an InputError and never
/// reaches libhdf5), then any number of datasets and root attributes are read from the one
/// open file. The layout is plain HDF5 behind a 512-byte user block, so h5py or the HDF5 C API
/// read it as well. Not thread-safe (libhdf5 is Debian's serial build).
class EpisodeFile {
 public:
  /// \throws InputError naming the file (no seal, length or checksum wrong, not HDF5).
  explicit EpisodeFile(const std::string& path);
  ~EpisodeFile();
  EpisodeFile(const EpisodeFile&) = delete;
  EpisodeFile& operator=(const EpisodeFile&) = delete;

  /// One numeric dataset (any numeric type, converted to double) with its dimensions; e.g.
  /// "/machines/ctl1/force_base_N". \throws InputError naming file and dataset (missing, over
  /// the memory budget, not numbers).
  std::vector<double> read(const std::string& dataset, std::vector<std::uint64_t>& dims) const;
  /// Whether `dataset` (an absolute path such as "/machines/ex1/arm/command_radps") exists.
  bool has(const std::string& dataset) const;
  /// A string attribute of the root group. \throws InputError naming it when missing or not a string.
  std::string rootAttribute(const std::string& name) const;
  const std::string& path() const { return path_; }

 private:
  std::string path_;
  std::int64_t file_ = -1;  // hid_t
};

/// EpisodeFile(path).read(dataset, dims): for one dataset. Reading several from one file, open
/// it once with EpisodeFile. \throws InputError naming file and dataset.
std::vector<double> readEpisodeDataset(const std::string& path, const std::string& dataset,
                                       std::vector<std::uint64_t>& dims);

/// A machine's truth base trajectory in an episode (`/machines/<id>/stamp`, `T_map_base`),
/// named after the file and dataset in messages. \throws InputError (the file's, a missing
/// machine, or matrices that do not match the stamps or are not rigid).
io::Trajectory episodeTrajectory(const EpisodeFile& file, const std::string& machine_id);

/// Wall seconds of one runEpisode call: `setup_s` builds the world (Simulator) and lays out the
/// file with its static parts (EpisodeWriter); `run_s` simulates and writes the rest, up to the
/// sealed file in place: the part BM_SimRealtime measures, plus the HDF5 writer.
struct EpisodeTiming {
  double setup_s = 0.0;       ///< building the world and laying out the file (wall s)
  double run_s = 0.0;         ///< the simulation and its writes, close included (wall s)
  double close_s = 0.0;       ///< of run_s, EpisodeWriter::close: the last writes, HDF5 close, seal, fsync
  EpisodeWriter::CloseTiming close_parts;  ///< close_s's parts
  double writer_cpu_s = 0.0;  ///< CPU seconds of the writer thread during the run
  /// Rays of every scan of the run, and of those the ones that took the hit kept from their
  /// sensor's previous scan (Simulator::Stats, SensorSpec::reuse_casts).
  std::uint64_t rays = 0, rays_kept = 0;
};

/// Runs a whole scenario into `dir`/episode.h5 (creating `dir`). Returns the file path; fills
/// `timing` when given. The HDF5 writes of the run go through a writer thread beside the
/// simulation (compression off its loop); the file's contents do not depend on it.
std::string runEpisode(const Scenario& scenario, const std::string& dir, EpisodeOptions options = {},
                       EpisodeTiming* timing = nullptr);

}  // namespace terramap::sim

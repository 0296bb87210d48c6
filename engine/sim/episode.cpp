// HDF5 episode writer (C API). Layout: docs/sim.md.
#include <terramap/core/error.hpp>
#include <terramap/core/memory_budget.hpp>
#include <terramap/io/file_seal.hpp>
#include <terramap/sim/episode.hpp>

#include "h5_detail.hpp"

#include <hdf5.h>
#include <fcntl.h>
#include <time.h>
#include <unistd.h>
#include <libdeflate.h>

#include <algorithm>
#include <array>
#include <chrono>
#include <cmath>
#include <cstring>
#include <condition_variable>
#include <deque>
#include <exception>
#include <filesystem>
#include <functional>
#include <map>
#include <memory>
#include <mutex>
#include <stdexcept>
#include <string_view>
#include <thread>

namespace terramap::sim {
namespace {

// libhdf5 closes every file still open when the process exits, and crashes doing so on a file
// whose close failed (a full disk: H5Fclose cannot flush, the file stays registered, and
// H5F__close_cb faults at exit). Files are closed explicitly here (or abandoned on failure), so
// that exit handler has nothing to do; it must be declined before the first HDF5 call, hence
// at load time.
[[maybe_unused]] const herr_t kNoHdf5AtExit = H5dont_atexit();

namespace fs = std::filesystem;
using h5detail::attrDouble;
using h5detail::attrDoubles;
using h5detail::attrString;
using h5detail::attrU64;
using h5detail::makeGroup;

/// A chunked dataset, shuffled and deflated at level `gzip` when gzip > 0.
/// \throws OutputError naming the file and the dataset.
hid_t createChunked(hid_t parent, const std::string& name, hid_t type, const std::vector<hsize_t>& dims,
                    const std::vector<hsize_t>& maxd, const std::vector<hsize_t>& chunk, int gzip,
                    const std::string& path) {
  const int rank = static_cast<int>(dims.size());
  const hid_t space = H5Screate_simple(rank, dims.data(), maxd.empty() ? nullptr : maxd.data());
  const hid_t dcpl = H5Pcreate(H5P_DATASET_CREATE);
  H5Pset_obj_track_times(dcpl, 0);  // see h5detail::makeGroup
  H5Pset_chunk(dcpl, rank, chunk.data());
  if (gzip > 0) {
    H5Pset_shuffle(dcpl);
    H5Pset_deflate(dcpl, static_cast<unsigned>(gzip));
  }
  const hid_t ds = H5Dcreate2(parent, name.c_str(), type, space, H5P_DEFAULT, dcpl, H5P_DEFAULT);
  H5Pclose(dcpl);
  H5Sclose(space);
  if (ds < 0) throw OutputError(path + ": cannot create dataset '" + name + "'");
  return ds;
}

/// The thread that makes the HDF5 calls once the file is laid out: compression (deflate on the
/// terrain snapshots and the clouds) and writes run beside the simulation instead of in its
/// loop. Debian's libhdf5 is the serial build: while the thread runs, no other thread touches
/// HDF5 (the writer's owner only queues jobs and, before its own HDF5 calls, drains them).
/// Jobs run in the order queued; the first one that throws stops the rest, and its exception
/// is rethrown to the owner by the next submit() or drain(). At most kMaxQueuedBytes of data wait
/// in the queue: beyond that submit() waits (the simulation would otherwise outrun the disk).
class WriterThread {
 public:
  static constexpr std::size_t kMaxQueuedBytes = std::size_t{256} << 20;
  ~WriterThread() { stop(); }
  /// From now on submit() queues (before, while the file is laid out, it runs jobs at once).
  void start() { async_ = true; }
  /// Runs `job` (HDF5 writes of `bytes` of data) at once before start(), else queues it.
  void submit(std::function<void()> job, std::size_t bytes) {
    if (!async_) {
      job();
      return;
    }
    std::unique_lock<std::mutex> lk(m_);
    rethrowLocked();
    if (!thread_.joinable()) thread_ = std::thread([this] { loop(); });
    space_.wait(lk, [&] { return queued_bytes_ == 0 || queued_bytes_ + bytes <= kMaxQueuedBytes || error_; });
    rethrowLocked();
    jobs_.push_back({std::move(job), bytes});
    queued_bytes_ += bytes;
    work_.notify_one();
  }
  /// Waits until every queued job ran. \throws the first job's exception.
  void drain() {
    std::unique_lock<std::mutex> lk(m_);
    idle_.wait(lk, [&] { return (jobs_.empty() && !busy_) || error_; });
    rethrowLocked();
  }
  /// Drops the jobs not started, waits for the running one and ends the thread.
  void stop() {
    {
      std::lock_guard<std::mutex> lk(m_);
      quit_ = true;
      jobs_.clear();
      queued_bytes_ = 0;
      work_.notify_one();
    }
    if (thread_.joinable()) thread_.join();
  }
  /// CPU seconds the thread used (its jobs and its waits' overhead); valid after stop().
  double cpuSeconds() const { return cpu_s_; }

 private:
  struct Job {
    std::function<void()> run;
    std::size_t bytes;
  };
  void rethrowLocked() {
    if (error_) std::rethrow_exception(error_);
  }
  void loop() {
    std::unique_lock<std::mutex> lk(m_);
    while (true) {
      work_.wait(lk, [&] { return quit_ || !jobs_.empty(); });
      if (quit_) {
        timespec ts{};
        if (::clock_gettime(CLOCK_THREAD_CPUTIME_ID, &ts) == 0)
          cpu_s_ = static_cast<double>(ts.tv_sec) + 1e-9 * static_cast<double>(ts.tv_nsec);
        return;
      }
      Job job = std::move(jobs_.front());
      jobs_.pop_front();
      busy_ = true;
      lk.unlock();
      std::exception_ptr err;
      try {
        job.run();
      } catch (...) {
        err = std::current_exception();
      }
      lk.lock();
      busy_ = false;
      queued_bytes_ -= job.bytes;
      if (err && !error_) {
        error_ = err;
        jobs_.clear();
        queued_bytes_ = 0;
      }
      space_.notify_all();
      if (jobs_.empty()) idle_.notify_all();
    }
  }
  std::mutex m_;
  std::condition_variable work_, space_, idle_;
  std::deque<Job> jobs_;
  std::size_t queued_bytes_ = 0;
  bool async_ = false, busy_ = false, quit_ = false;
  std::exception_ptr error_;
  double cpu_s_ = 0.0;  // written by the thread as it ends, read after join
  std::thread thread_;
};

/// An HDF5 dataset growing along its first dimension, with rows buffered in memory; full
/// buffers go to `writer` (at once until it is started; without one, at once).
class Appender {
 public:
  Appender() = default;
  Appender(hid_t parent, const std::string& name, hid_t type, std::vector<hsize_t> row_dims, int gzip,
           const std::string& path, WriterThread* writer, hsize_t chunk_rows = 1024)
      : type_(type), row_dims_(std::move(row_dims)), path_(path), name_(name), writer_(writer) {
    row_elems_ = 1;
    for (hsize_t d : row_dims_) row_elems_ *= d;
    elem_size_ = H5Tget_size(type);
    std::vector<hsize_t> dims{0}, maxd{H5S_UNLIMITED}, chunk{chunk_rows};
    for (hsize_t d : row_dims_) {
      dims.push_back(d);
      maxd.push_back(d);
      chunk.push_back(d);
    }
    ds_ = createChunked(parent, name, type, dims, maxd, chunk, gzip, path_);
  }
  Appender(Appender&& o) noexcept { *this = std::move(o); }
  Appender& operator=(Appender&& o) noexcept {
    std::swap(ds_, o.ds_);
    type_ = o.type_; row_dims_ = o.row_dims_; row_elems_ = o.row_elems_; elem_size_ = o.elem_size_;
    rows_ = o.rows_; buf_ = std::move(o.buf_); path_ = o.path_; name_ = o.name_; writer_ = o.writer_;
    return *this;
  }
  ~Appender() {
    if (ds_ >= 0) H5Dclose(ds_);
  }
  template <class T>
  void append(const T* row, std::size_t nrows = 1) {
    const char* p = reinterpret_cast<const char*>(row);
    buf_.insert(buf_.end(), p, p + nrows * row_elems_ * elem_size_);
    if (buf_.size() > (1u << 20)) flush();
  }
  /// Appends the rows of `rows` (whole rows of this dataset's element type), taking the vector
  /// instead of copying it into the buffer; the rows buffered before it go first.
  template <class T>
  void appendOwned(std::vector<T>&& rows) {
    if (rows.empty()) return;
    flush();
    if (ds_ < 0) return;
    const std::size_t bytes = rows.size() * sizeof(T);
    if (!writer_) {
      write(reinterpret_cast<const char*>(rows.data()), bytes);
      return;
    }
    auto held = std::make_shared<std::vector<T>>(std::move(rows));
    writer_->submit([this, held, bytes] { write(reinterpret_cast<const char*>(held->data()), bytes); }, bytes);
  }
  void flush() {
    if (buf_.empty() || ds_ < 0) return;
    if (!writer_) {
      write(buf_.data(), buf_.size());
      buf_.clear();
      return;
    }
    // The rows go to the writer; this Appender stays where it is until the writer is drained
    // (both live in the EpisodeWriter's Impl), so the job may refer to it.
    auto rows = std::make_shared<std::vector<char>>(std::move(buf_));
    buf_ = std::vector<char>();
    const std::size_t bytes = rows->size();
    writer_->submit([this, rows] { write(rows->data(), rows->size()); }, bytes);
  }

 private:
  void write(const char* data, std::size_t size) {
    const hsize_t n = size / (row_elems_ * elem_size_);
    std::vector<hsize_t> dims{rows_ + n}, start{rows_}, count{n};
    for (hsize_t d : row_dims_) {
      dims.push_back(d);
      start.push_back(0);
      count.push_back(d);
    }
    if (H5Dset_extent(ds_, dims.data()) < 0) throw OutputError(path_ + ": cannot extend '" + name_ + "'");
    const hid_t fs_ = H5Dget_space(ds_);
    H5Sselect_hyperslab(fs_, H5S_SELECT_SET, start.data(), nullptr, count.data(), nullptr);
    const hid_t ms = H5Screate_simple(static_cast<int>(count.size()), count.data(), nullptr);
    const herr_t rc = H5Dwrite(ds_, type_, ms, fs_, H5P_DEFAULT, data);
    H5Sclose(ms);
    H5Sclose(fs_);
    if (rc < 0) throw OutputError(path_ + ": cannot write '" + name_ + "' (disk full?)");
    rows_ += n;
  }

  hid_t ds_ = -1;
  hid_t type_ = -1;
  std::vector<hsize_t> row_dims_;
  hsize_t row_elems_ = 1, rows_ = 0;
  std::size_t elem_size_ = 8;
  std::vector<char> buf_;
  std::string path_, name_;
  WriterThread* writer_ = nullptr;
};

/// A series of ny x nx float grids (the terrain snapshots): dataset [k, ny, nx] in chunks of
/// 1 x 128 x 128, HDF5's shuffle and deflate filters when compressed. The terrain changes only
/// where the machines work, so most chunks of a snapshot equal the previous snapshot's: the
/// simulating thread converts only the chunks the terrain's revisions say may have changed
/// (TruthTerrain::changedSince), the others are written as the bytes already compressed for them
/// (H5Dwrite_chunk), and a converted chunk is shuffled and deflated only when its values did
/// change, in the layout HDF5's shuffle and deflate filters decode (any HDF5 reader reads the
/// file as before). Why each step: the writer thread's CPU is taken from the simulation's two
/// cores, so deflating only what changed, with libdeflate (the same zlib stream, about half
/// zlib's CPU), in chunks of 128 nodes a side (a working machine changes a few square metres a
/// second; larger chunks deflate more of what did not change) is what keeps `terramap sim` near
/// the benchmark (docs/sim.md, "Writing the episode", has the before/after and their commands).
///
/// Tried and not kept: each chunk version stored once and <name> an HDF5 virtual dataset mapping
/// every (snapshot, chunk) onto its version. The file halves, but reading and writing a virtual
/// dataset scale with its mappings (an hour of 1 s snapshots would be 130 k per layer); see
/// docs/sim.md for what was measured.
class GridSeries {
 public:
  static constexpr int kChunk = 128;  // nodes a side
  GridSeries() = default;
  GridSeries(hid_t parent, const std::string& name, int nx, int ny, int gzip, const std::string& path)
      : nx_(nx), ny_(ny), gzip_(gzip), path_(path), name_(name) {
    cx_ = std::min(nx, kChunk);
    cy_ = std::min(ny, kChunk);
    ncx_ = (nx + cx_ - 1) / cx_;
    ncy_ = (ny + cy_ - 1) / cy_;
    const hsize_t y = static_cast<hsize_t>(ny), x = static_cast<hsize_t>(nx);
    ds_ = createChunked(parent, name, H5T_NATIVE_FLOAT, {0, y, x}, {H5S_UNLIMITED, y, x},
                        {1, static_cast<hsize_t>(cy_), static_cast<hsize_t>(cx_)}, gzip, path_);
    prev_.resize(static_cast<std::size_t>(ncx_) * static_cast<std::size_t>(ncy_));
    packed_.resize(prev_.size());
  }
  GridSeries(GridSeries&& o) noexcept { *this = std::move(o); }
  GridSeries& operator=(GridSeries&& o) noexcept {
    std::swap(ds_, o.ds_);
    nx_ = o.nx_, ny_ = o.ny_, gzip_ = o.gzip_, cx_ = o.cx_, cy_ = o.cy_, ncx_ = o.ncx_, ncy_ = o.ncy_;
    count_ = o.count_, path_ = o.path_, name_ = o.name_;
    prev_ = std::move(o.prev_);
    packed_ = std::move(o.packed_);
    shuffled_ = std::move(o.shuffled_);
    deflater_ = std::move(o.deflater_);
    return *this;
  }
  ~GridSeries() {
    if (ds_ >= 0) H5Dclose(ds_);
  }
  int chunks() const { return ncx_ * ncy_; }
  std::size_t chunkValues() const { return static_cast<std::size_t>(cx_) * static_cast<std::size_t>(cy_); }
  /// Node box of chunk k (inclusive, clipped to the grid).
  void chunkBox(int k, int& i0, int& j0, int& i1, int& j1) const {
    i0 = (k % ncx_) * cx_, j0 = (k / ncx_) * cy_;
    i1 = std::min(nx_, i0 + cx_) - 1, j1 = std::min(ny_, j0 + cy_) - 1;
  }
  /// Chunk k of the row-major grid `g` as stored: cy x cx floats, the part past the grid's edge 0.
  /// Reads only immutable geometry: callable on the simulating thread beside write().
  void packChunk(int k, const double* g, float* out) const {
    int i0, j0, i1, j1;
    chunkBox(k, i0, j0, i1, j1);
    std::fill(out, out + chunkValues(), 0.0f);
    for (int j = j0; j <= j1; ++j) {
      const double* src = g + static_cast<std::size_t>(j) * nx_ + i0;
      float* dst = out + static_cast<std::size_t>(j - j0) * cx_;
      for (int i = 0; i <= i1 - i0; ++i) dst[i] = static_cast<float>(src[i]);
    }
  }
  /// Appends one grid: the chunks listed in `changed` (ascending) come from `data`
  /// (changed.size() x chunkValues(), as packChunk gives them), every other chunk equals the
  /// previous grid's. The first grid must list every chunk. HDF5 calls: on the writer thread's side.
  void write(const std::vector<int>& changed, const float* data) {
    if (ds_ < 0) return;
    if (count_ == 0 && static_cast<int>(changed.size()) != chunks())
      throw std::logic_error("GridSeries::write: the first grid must give every chunk");
    hsize_t dims[3] = {count_ + 1, static_cast<hsize_t>(ny_), static_cast<hsize_t>(nx_)};
    if (H5Dset_extent(ds_, dims) < 0) throw OutputError(path_ + ": cannot extend '" + name_ + "'");
    const std::size_t n = chunkValues();
    std::vector<unsigned char>& shuffled = shuffled_;
    shuffled.resize(gzip_ > 0 ? n * sizeof(float) : 0);
    for (std::size_t c = 0; c < changed.size(); ++c) {
      const std::size_t k = static_cast<std::size_t>(changed[c]);
      const float* raw = data + c * n;
      if (count_ > 0 && std::memcmp(prev_[k].data(), raw, n * sizeof(float)) == 0) continue;
      prev_[k].assign(raw, raw + n);
      std::vector<unsigned char>& packed = packed_[k];
      if (gzip_ > 0) {
        // HDF5's shuffle filter: byte b of every element, for b = 0..3, one plane after another.
        const unsigned char* src = reinterpret_cast<const unsigned char*>(raw);
        for (std::size_t e = 0; e < n; ++e)
          for (std::size_t b = 0; b < sizeof(float); ++b) shuffled[b * n + e] = src[e * sizeof(float) + b];
        if (!deflater_) deflater_.reset(libdeflate_alloc_compressor(std::min(gzip_, 12)));
        if (!deflater_) throw std::bad_alloc();
        packed.resize(libdeflate_zlib_compress_bound(deflater_.get(), shuffled.size()));
        const std::size_t len =
            libdeflate_zlib_compress(deflater_.get(), shuffled.data(), shuffled.size(), packed.data(), packed.size());
        if (len == 0) throw OutputError(path_ + ": cannot compress a chunk of '" + name_ + "'");
        packed.resize(len);
      } else {
        packed.assign(reinterpret_cast<const unsigned char*>(raw), reinterpret_cast<const unsigned char*>(raw + n));
      }
    }
    for (int k = 0; k < chunks(); ++k) {
      const hsize_t offset[3] = {count_, static_cast<hsize_t>((k / ncx_) * cy_), static_cast<hsize_t>((k % ncx_) * cx_)};
      const std::vector<unsigned char>& packed = packed_[static_cast<std::size_t>(k)];
      if (H5Dwrite_chunk(ds_, H5P_DEFAULT, 0, offset, packed.size(), packed.data()) < 0)
        throw OutputError(path_ + ": cannot write '" + name_ + "' (disk full?)");
    }
    ++count_;
  }

 private:
  hid_t ds_ = -1;
  int nx_ = 0, ny_ = 0, gzip_ = 0, cx_ = 1, cy_ = 1, ncx_ = 0, ncy_ = 0;
  hsize_t count_ = 0;
  std::string path_, name_;
  std::vector<std::vector<float>> prev_;            // per chunk: its last stored values
  std::vector<std::vector<unsigned char>> packed_;  // per chunk: its last stored bytes
  std::vector<unsigned char> shuffled_;             // one chunk in the shuffle filter's byte order
  struct FreeDeflater {
    void operator()(libdeflate_compressor* c) const { libdeflate_free_compressor(c); }
  };
  std::unique_ptr<libdeflate_compressor, FreeDeflater> deflater_;
};

void writeGrid(hid_t parent, const std::string& name, const std::vector<float>& data, int nx, int ny, int gzip,
               const std::string& path) {
  const hsize_t y = static_cast<hsize_t>(ny), x = static_cast<hsize_t>(nx);
  const hid_t ds = createChunked(parent, name, H5T_NATIVE_FLOAT, {y, x}, {},
                                 {std::min<hsize_t>(y, 256), std::min<hsize_t>(x, 256)}, gzip, path);
  if (H5Dwrite(ds, H5T_NATIVE_FLOAT, H5S_ALL, H5S_ALL, H5P_DEFAULT, data.data()) < 0) {
    H5Dclose(ds);
    throw OutputError(path + ": cannot write grid '" + name + "'");
  }
  H5Dclose(ds);
}

/// Estimate minus truth: position (map frame, m) and the rotation vector of R_est * R_true^T
/// (map frame, rad; for small errors roll, pitch, yaw about the map axes).
void poseError(const Eigen::Isometry3d& est, const Eigen::Isometry3d& truth, double* out) {
  const Eigen::Vector3d dp = est.translation() - truth.translation();
  const Eigen::AngleAxisd aa(est.linear() * truth.linear().transpose());
  const Eigen::Vector3d dr = aa.axis() * aa.angle();
  for (int k = 0; k < 3; ++k) {
    out[k] = dp[k];
    out[3 + k] = dr[k];
  }
}

void rowMajor4x4(const Eigen::Isometry3d& T, double* out) {
  const Eigen::Matrix4d M = T.matrix();
  for (int r = 0; r < 4; ++r)
    for (int c = 0; c < 4; ++c) out[r * 4 + c] = M(r, c);
}

struct MachineSets {
  hid_t group = -1, truth = -1, estimate = -1, clouds = -1;
  std::map<std::string, Appender> a;  // by dataset path
  struct Cloud { hid_t group = -1; Appender stamp, T, offset, count, points; std::uint64_t total = 0; };
  std::map<std::string, Cloud> cloud;  // by frame "<machine>/<sensor>"
  struct Imu { hid_t group = -1; Appender stamp, accel, gyro; };
  std::map<std::string, Imu> imu;      // by frame "<machine>/<sensor>"
};

}  // namespace

struct EpisodeWriter::Impl {
  /// What one snapshot hands the writer thread: only the chunks that may have changed.
  struct SnapshotChunks {
    std::vector<int> changed;   // chunk indices, ascending
    std::vector<float> h, l;    // changed.size() x chunkValues() each (height, loose)
  };
  WriterThread writer;  // started once the file is laid out; stopped by closeAll() before any other HDF5 call
  std::string final_path, tmp_path;
  EpisodeOptions opt;
  hid_t file = -1, terrain = -1;
  /// The temporary file once more, read-only: the writer thread asks the kernel to start writing
  /// its pages to disk after each snapshot (sync_file_range), so the seal's fsync at close, after
  /// the simulation, finds little left to wait for (`terramap sim` prints the close's time).
  int writeback_fd = -1;
  Appender snap_stamp;
  GridSeries snap_height, snap_loose;
  int nx = 0, ny = 0;
  double next_snapshot = 0, snapshot_interval = 1;
  double last_snapshot_t = -1;
  std::uint64_t snap_terrain = 0;   // instanceId() of the terrain the last snapshot read (0: none yet)
  std::uint64_t snap_revision = 0;  // its revision() then
  std::vector<MachineSets> machines;
  std::map<std::string, std::size_t, std::less<>> machine_index;
  /// The machine of a frame "<machine>/<name>" (-1 if no such machine); `bare` for a frame
  /// without the prefix (a lone machine's "base": 0; a sensor's frame always has one: -1).
  long machineOfFrame(std::string_view frame, long bare) const {
    const std::size_t slash = frame.find('/');
    if (slash == std::string_view::npos) return bare;
    const auto it = machine_index.find(frame.substr(0, slash));
    return it == machine_index.end() ? -1 : static_cast<long>(it->second);
  }
  bool closed = false;
  double writer_cpu_s = 0.0;  // the writer thread's CPU seconds, once closed
  EpisodeWriter::CloseTiming close_timing;

  /// The terrain now, handed to the writer thread. This runs on the simulating thread between
  /// two periods, so it only converts, and only the chunks that may have changed since the last
  /// snapshot (all of them the first time); the comparison, shuffling and deflating happen on
  /// the writer thread.
  void snapshot(const Simulator& sim) {
    const TruthTerrain& t = sim.truth();
    // Shared: std::function needs a copyable job.
    const auto s = std::make_shared<SnapshotChunks>();
    const bool all = snap_terrain != t.instanceId();
    for (int k = 0; k < snap_height.chunks(); ++k) {
      int i0, j0, i1, j1;
      snap_height.chunkBox(k, i0, j0, i1, j1);
      if (all || t.changedSince(snap_revision, i0, j0, i1, j1)) s->changed.push_back(k);
    }
    snap_terrain = t.instanceId();
    snap_revision = t.revision();
    const std::size_t per = snap_height.chunkValues();
    s->h.resize(s->changed.size() * per);
    s->l.resize(s->changed.size() * per);
    for (std::size_t c = 0; c < s->changed.size(); ++c) {
      snap_height.packChunk(s->changed[c], t.heightData().data(), &s->h[c * per]);
      snap_loose.packChunk(s->changed[c], t.looseData().data(), &s->l[c * per]);
    }
    const double st = sim.time();
    snap_stamp.append(&st);
    auto job = [this, s] {
      snap_height.write(s->changed, s->h.data());
      snap_loose.write(s->changed, s->l.data());
    };
    writer.submit(job, (s->h.size() + s->l.size()) * sizeof(float));
    if (writeback_fd >= 0) {
      const int fd = writeback_fd;
      // Only starts the writeback (no wait) and cannot lose data: a failure here leaves it to fsync.
      writer.submit([fd] { ::sync_file_range(fd, 0, 0, SYNC_FILE_RANGE_WRITE); }, 0);
    }
    last_snapshot_t = st;
  }
  void closeAll() {
    writer.stop();
    writer_cpu_s = writer.cpuSeconds();
    for (auto& m : machines) {
      for (auto& [k, c] : m.cloud) {
        c.stamp = Appender(); c.T = Appender(); c.offset = Appender(); c.count = Appender(); c.points = Appender();
        if (c.group >= 0) H5Gclose(c.group);
      }
      for (auto& [k, u] : m.imu) {
        u.stamp = Appender(); u.accel = Appender(); u.gyro = Appender();
        if (u.group >= 0) H5Gclose(u.group);
      }
      m.a.clear();
      if (m.clouds >= 0) H5Gclose(m.clouds);
      if (m.truth >= 0) H5Gclose(m.truth);
      if (m.estimate >= 0) H5Gclose(m.estimate);
      if (m.group >= 0) H5Gclose(m.group);
    }
    machines.clear();
    snap_stamp = Appender(); snap_height = GridSeries(); snap_loose = GridSeries();
    if (terrain >= 0) H5Gclose(terrain);
    terrain = -1;
    if (file >= 0) H5Fclose(file);
    file = -1;
    if (writeback_fd >= 0) ::close(writeback_fd);
    writeback_fd = -1;
  }
  void writeSoilMaps(const Simulator& sim, const EpisodeOptions& options);
  /// EpisodeWriter::record; `owned`: the same vector as `events` when its clouds may be taken.
  void record(const Simulator& sim, const std::vector<Event>& events, std::vector<Event>* owned);
  void openMachine(hid_t mg, const MachineSpec& spec, std::size_t mi, const EpisodeOptions& options);
};

/// The surface soil maps (depth 0 below the initial surface) and the zone index, /soil.
void EpisodeWriter::Impl::writeSoilMaps(const Simulator& sim, const EpisodeOptions& options) {
  Impl& I = *this;
  const TruthTerrain& t = sim.truth();
  const hid_t soil = makeGroup(I.file, "soil", I.tmp_path);
  const char* names[] = {"c_pa", "phi_rad", "gamma_n_m3", "ca_pa", "delta_rad", "relative_density", "zone"};
  std::vector<std::vector<float>> maps(7, std::vector<float>(static_cast<std::size_t>(I.nx) * I.ny));
  for (int j = 0; j < I.ny; ++j)
    for (int i = 0; i < I.nx; ++i) {
      const Eigen::Vector2d p = t.nodePosition(i, j);
      const int z = sim.soil().zoneAt(p.x(), p.y(), 0.0);
      const SoilProperties& s = sim.soil().at(p.x(), p.y(), 0.0);
      const std::size_t k = static_cast<std::size_t>(j) * I.nx + i;
      maps[0][k] = static_cast<float>(s.fee.c_pa);
      maps[1][k] = static_cast<float>(s.fee.phi_rad);
      maps[2][k] = static_cast<float>(s.fee.gamma_n_m3);
      maps[3][k] = static_cast<float>(s.fee.ca_pa);
      maps[4][k] = static_cast<float>(s.fee.delta_rad);
      maps[5][k] = static_cast<float>(s.relative_density);
      maps[6][k] = static_cast<float>(z);
    }
  for (int m = 0; m < 7; ++m) writeGrid(soil, names[m], maps[m], I.nx, I.ny, std::max(1, options.compression), I.tmp_path);
  H5Gclose(soil);
}

/// One machine's group: its per-observation datasets (truth at top level, estimate/, truth/)
/// and, with clouds, one group per LiDAR.
void EpisodeWriter::Impl::openMachine(hid_t mg, const MachineSpec& spec, std::size_t mi, const EpisodeOptions& options) {
  Impl& I = *this;
  MachineSets& M = I.machines[mi];
  I.machine_index[spec.id] = mi;
  M.group = makeGroup(mg, spec.id, I.tmp_path);
  attrDouble(M.group, "blade_width_m", spec.blade.width_m);
  attrDouble(M.group, "blade_height_m", spec.blade.height_m);
  auto add = [&](hid_t parent, const std::string& key, const std::string& name, hid_t type, std::vector<hsize_t> row) {
    M.a.emplace(key, Appender(parent, name, type, std::move(row), 0, I.tmp_path, &I.writer));
  };
  add(M.group, "stamp", "stamp", H5T_NATIVE_DOUBLE, {});
  add(M.group, "T_map_base", "T_map_base", H5T_NATIVE_DOUBLE, {4, 4});
  add(M.group, "twist_base", "twist_base", H5T_NATIVE_DOUBLE, {6});
  add(M.group, "T_map_blade", "T_map_blade", H5T_NATIVE_DOUBLE, {4, 4});
  add(M.group, "twist_blade", "twist_blade", H5T_NATIVE_DOUBLE, {6});
  add(M.group, "cylinder_length_m", "cylinder_length_m", H5T_NATIVE_DOUBLE, {3});
  add(M.group, "cylinder_velocity_mps", "cylinder_velocity_mps", H5T_NATIVE_DOUBLE, {3});
  add(M.group, "track_speed_mps", "track_speed_mps", H5T_NATIVE_DOUBLE, {2});
  add(M.group, "engine_speed_rpm", "engine_speed_rpm", H5T_NATIVE_DOUBLE, {});
  add(M.group, "action", "action", H5T_NATIVE_DOUBLE, {5});
  add(M.group, "force_base_N", "force_base_N", H5T_NATIVE_DOUBLE, {3});
  add(M.group, "pose_T_map_base", "pose_T_map_base", H5T_NATIVE_DOUBLE, {4, 4});
  M.estimate = makeGroup(M.group, "estimate", I.tmp_path);
  add(M.estimate, "e_T_map_base", "T_map_base", H5T_NATIVE_DOUBLE, {4, 4});
  add(M.estimate, "e_twist_base", "twist_base", H5T_NATIVE_DOUBLE, {6});
  add(M.estimate, "e_T_map_blade", "T_map_blade", H5T_NATIVE_DOUBLE, {4, 4});
  add(M.estimate, "e_twist_blade", "twist_blade", H5T_NATIVE_DOUBLE, {6});
  add(M.estimate, "e_cylinder_length_m", "cylinder_length_m", H5T_NATIVE_DOUBLE, {3});
  add(M.estimate, "e_error_base", "error_base", H5T_NATIVE_DOUBLE, {6});
  add(M.estimate, "e_error_blade", "error_blade", H5T_NATIVE_DOUBLE, {6});
  M.truth = makeGroup(M.group, "truth", I.tmp_path);
  add(M.truth, "t_force_map_N", "force_map_N", H5T_NATIVE_DOUBLE, {3});
  add(M.truth, "t_force_base_N", "force_base_N", H5T_NATIVE_DOUBLE, {3});
  add(M.truth, "t_force_quiet_map_N", "force_quiet_map_N", H5T_NATIVE_DOUBLE, {3});
  add(M.truth, "t_fee", "fee", H5T_NATIVE_DOUBLE, {6});
  add(M.truth, "t_soil", "soil", H5T_NATIVE_DOUBLE, {5});
  add(M.truth, "t_stalled", "stalled", H5T_NATIVE_UINT8, {});
  add(M.truth, "t_setpoints", "setpoints", H5T_NATIVE_DOUBLE, {5});
  add(M.truth, "t_cut", "cut_bank_m3", H5T_NATIVE_DOUBLE, {});
  if (spec.arm) {
    // The manipulator's joint states (TERA's JointState: position, velocity, effort), the
    // encoders' reading, the levers, the bucket pose and its load.
    const hid_t arm = makeGroup(M.group, "arm", I.tmp_path);
    attrString(arm, "joints", "slew,boom,arm,bucket");
    attrDouble(arm, "bucket_width_m", spec.arm->bucket_width_m);
    add(arm, "a_q", "joint_position_rad", H5T_NATIVE_DOUBLE, {4});
    add(arm, "a_qd", "joint_velocity_radps", H5T_NATIVE_DOUBLE, {4});
    add(arm, "a_tau", "joint_torque_Nm", H5T_NATIVE_DOUBLE, {4});
    add(arm, "a_qm", "joint_measured_rad", H5T_NATIVE_DOUBLE, {4});
    add(arm, "a_lever", "lever", H5T_NATIVE_DOUBLE, {4});
    add(arm, "a_cmd", "command_radps", H5T_NATIVE_DOUBLE, {4});
    add(arm, "a_incl", "inclination_rad", H5T_NATIVE_DOUBLE, {3});
    add(arm, "a_inclm", "inclination_measured_rad", H5T_NATIVE_DOUBLE, {3});
    add(arm, "a_stalled", "stalled_mask", H5T_NATIVE_UINT8, {});
    add(arm, "a_phase", "phase", H5T_NATIVE_INT32, {});
    add(arm, "a_T_bucket", "T_map_bucket", H5T_NATIVE_DOUBLE, {4, 4});
    add(arm, "a_force", "bucket_force_map_N", H5T_NATIVE_DOUBLE, {3});
    add(arm, "a_load", "bucket_load", H5T_NATIVE_DOUBLE, {3});
    add(arm, "a_moved", "bucket_moved_bank_m3", H5T_NATIVE_DOUBLE, {2});
  }
  bool any_imu = false;
  for (const SensorSpec& s : spec.sensors) any_imu |= s.type == SensorSpec::Type::Imu;
  if (any_imu) {
    const hid_t imus = makeGroup(M.group, "imu", I.tmp_path);
    for (const SensorSpec& s : spec.sensors) {
      if (s.type != SensorSpec::Type::Imu) continue;
      MachineSets::Imu u;
      u.group = makeGroup(imus, s.id, I.tmp_path);
      attrString(u.group, "link", linkName(s.link));
      attrDouble(u.group, "rate_hz", s.rate_hz);
      double T[16];
      rowMajor4x4(s.T_base_sensor, T);
      attrDoubles(u.group, "T_link_imu", T, 16);
      u.stamp = Appender(u.group, "stamp", H5T_NATIVE_DOUBLE, {}, 0, I.tmp_path, &I.writer, 1024);
      u.accel = Appender(u.group, "accel_mps2", H5T_NATIVE_DOUBLE, {3}, 0, I.tmp_path, &I.writer, 1024);
      u.gyro = Appender(u.group, "gyro_radps", H5T_NATIVE_DOUBLE, {3}, 0, I.tmp_path, &I.writer, 1024);
      M.imu.emplace(spec.id + "/" + s.id, std::move(u));
    }
    H5Gclose(imus);
  }
  if (options.clouds) {
    M.clouds = makeGroup(M.group, "clouds", I.tmp_path);
    for (const SensorSpec& s : spec.sensors) {
      if (!s.castsRays()) continue;
      MachineSets::Cloud c;
      c.group = makeGroup(M.clouds, s.id, I.tmp_path);
      if (s.type == SensorSpec::Type::DepthCamera) {
        attrString(c.group, "kind", "depth_camera");
        attrU64(c.group, "width", static_cast<std::uint64_t>(s.width));
        attrU64(c.group, "height", static_cast<std::uint64_t>(s.height));
        attrDouble(c.group, "fx", s.fx);
        attrDouble(c.group, "fy", s.fy);
        attrDouble(c.group, "cx", s.cx);
        attrDouble(c.group, "cy", s.cy);
      } else {
        attrString(c.group, "kind", "lidar");
        attrU64(c.group, "beams", static_cast<std::uint64_t>(s.beams));
        attrU64(c.group, "columns", static_cast<std::uint64_t>(s.columns));
      }
      attrString(c.group, "link", linkName(s.link));
      c.stamp = Appender(c.group, "stamp", H5T_NATIVE_DOUBLE, {}, 0, I.tmp_path, &I.writer, 256);
      c.T = Appender(c.group, "T_map_sensor", H5T_NATIVE_DOUBLE, {4, 4}, 0, I.tmp_path, &I.writer, 256);
      c.offset = Appender(c.group, "offset", H5T_NATIVE_UINT64, {}, 0, I.tmp_path, &I.writer, 256);
      c.count = Appender(c.group, "count", H5T_NATIVE_UINT64, {}, 0, I.tmp_path, &I.writer, 256);
      c.points = Appender(c.group, "points", H5T_NATIVE_FLOAT, {4}, options.cloud_compression, I.tmp_path, &I.writer, 65536);
      M.cloud.emplace(spec.id + "/" + s.id, std::move(c));
    }
  }
}

EpisodeWriter::EpisodeWriter(const std::string& path, const Simulator& sim, EpisodeOptions options)
    : impl_(std::make_unique<Impl>()) {
  Impl& I = *impl_;
  I.final_path = path;
  I.tmp_path = path + ".tmp-" + std::to_string(::getpid());
  I.opt = options;
  H5Eset_auto2(H5E_DEFAULT, nullptr, nullptr);  // errors become OutputError, not stderr noise
  // Room for the seal (io/file_seal.hpp), written once the file is complete.
  const hid_t fcpl = H5Pcreate(H5P_FILE_CREATE);
  H5Pset_userblock(fcpl, io::kSealBytes);
  H5Pset_obj_track_times(fcpl, 0);  // the root group too (h5detail::makeGroup)
  I.file = H5Fcreate(I.tmp_path.c_str(), H5F_ACC_TRUNC, fcpl, H5P_DEFAULT);
  H5Pclose(fcpl);
  if (I.file < 0) throw OutputError(I.tmp_path + ": cannot create HDF5 file");
  // A constructor that throws runs no destructor: if laying out the file fails (a full disk),
  // the file is closed and the temporary removed here, not left open until exit.
  struct Abandon {
    Impl& I;
    bool armed = true;
    ~Abandon() {
      if (!armed) return;
      try {
        I.closeAll();
      } catch (...) {  // NOLINT: the error that brought us here is the one reported
      }
      std::error_code ec;
      fs::remove(I.tmp_path, ec);
    }
  } abandon{I};
  const Scenario& sc = sim.scenario();
  attrString(I.file, "format", "terramap-sim-episode");
  // Version 2: top-level poses are the truth, estimate/ holds what the mapper received.
  attrU64(I.file, "version", 2);
  attrString(I.file, "scenario_name", sc.name);
  attrString(I.file, "scenario_yaml", sc.yaml_text);
  attrU64(I.file, "seed", sc.seed);
  attrDouble(I.file, "duration_s", sc.duration_s);
  attrDouble(I.file, "observation_hz", sc.observation_hz);
  attrDouble(I.file, "physics_hz", sc.physics_hz);
  // Terrain.
  const TruthTerrain& t = sim.truth();
  I.nx = t.nx();
  I.ny = t.ny();
  I.terrain = makeGroup(I.file, "terrain", I.tmp_path);
  attrDouble(I.terrain, "origin_x_m", t.originX());
  attrDouble(I.terrain, "origin_y_m", t.originY());
  attrDouble(I.terrain, "resolution_m", t.resolution());
  attrU64(I.terrain, "nx", static_cast<std::uint64_t>(t.nx()));
  attrU64(I.terrain, "ny", static_cast<std::uint64_t>(t.ny()));
  std::vector<float> g(static_cast<std::size_t>(I.nx) * I.ny);
  for (int j = 0; j < I.ny; ++j)
    for (int i = 0; i < I.nx; ++i) g[static_cast<std::size_t>(j) * I.nx + i] = static_cast<float>(t.initialHeight(i, j));
  writeGrid(I.terrain, "initial_height", g, I.nx, I.ny, options.compression, I.tmp_path);
  I.snap_stamp = Appender(I.terrain, "snapshot_stamp", H5T_NATIVE_DOUBLE, {}, 0, I.tmp_path, &I.writer, 64);
  I.snap_height = GridSeries(I.terrain, "height", I.nx, I.ny, options.compression, I.tmp_path);
  I.snap_loose = GridSeries(I.terrain, "loose", I.nx, I.ny, options.compression, I.tmp_path);
  I.snapshot_interval = sc.terrain.snapshot_interval_s;
  I.writeSoilMaps(sim, options);
  // Machines.
  const hid_t mg = makeGroup(I.file, "machines", I.tmp_path);
  I.machines.resize(sim.machineCount());
  for (std::size_t mi = 0; mi < sim.machineCount(); ++mi) I.openMachine(mg, sc.machines[mi], mi, options);
  H5Gclose(mg);
  I.writeback_fd = ::open(I.tmp_path.c_str(), O_RDONLY | O_CLOEXEC);  // -1: no early writeback, no harm
  I.snapshot(sim);
  I.next_snapshot = I.snapshot_interval;
  I.writer.start();
  abandon.armed = false;
}

EpisodeWriter::~EpisodeWriter() {
  if (impl_ && !impl_->closed) {
    try {
      impl_->closeAll();
    } catch (...) {
    }
    std::error_code ec;
    fs::remove(impl_->tmp_path, ec);
  }
}

void EpisodeWriter::record(const Simulator& sim, const std::vector<Event>& events) { impl_->record(sim, events, nullptr); }

void EpisodeWriter::record(const Simulator& sim, std::vector<Event>&& events) { impl_->record(sim, events, &events); }

double EpisodeWriter::writerCpuSeconds() const { return impl_->writer_cpu_s; }
EpisodeWriter::CloseTiming EpisodeWriter::closeTiming() const { return impl_->close_timing; }

void EpisodeWriter::Impl::record(const Simulator& sim, const std::vector<Event>& events, std::vector<Event>* owned) {
  for (std::size_t ei = 0; ei < events.size(); ++ei) {
    const Event& e = events[ei];
    if (const auto* pc = std::get_if<PointCloud>(&e)) {
      if (!opt.clouds) continue;
      const long mi = machineOfFrame(pc->frame, -1);
      if (mi < 0) continue;
      auto cit = machines[static_cast<std::size_t>(mi)].cloud.find(pc->frame);
      if (cit == machines[static_cast<std::size_t>(mi)].cloud.end()) continue;
      MachineSets::Cloud& c = cit->second;
      double T[16];
      rowMajor4x4(pc->T_map_sensor, T);
      const std::uint64_t off = c.total, cnt = pc->points.size();
      c.stamp.append(&pc->stamp);
      c.T.append(T);
      c.offset.append(&off);
      c.count.append(&cnt);
      static_assert(sizeof(PointXYZI) == 4 * sizeof(float), "a stored point is 4 floats");
      // The clouds are most of an episode's bytes: taken, not copied, when the caller gives the events away.
      if (cnt && owned) c.points.appendOwned(std::move(std::get<PointCloud>((*owned)[ei]).points));
      else if (cnt) c.points.append(reinterpret_cast<const float*>(pc->points.data()), cnt);
      c.total += cnt;
    } else if (const auto* im = std::get_if<ImuSample>(&e)) {
      const long mi = machineOfFrame(im->frame, -1);
      if (mi < 0) continue;
      auto uit = machines[static_cast<std::size_t>(mi)].imu.find(im->frame);
      if (uit == machines[static_cast<std::size_t>(mi)].imu.end()) continue;
      uit->second.stamp.append(&im->stamp);
      uit->second.accel.append(im->accel_mps2.data());
      uit->second.gyro.append(im->gyro_radps.data());
    } else if (const auto* ps = std::get_if<Pose>(&e)) {
      // Pose frames are "base" (one machine) or "<machine>/base".
      const long mi = machineOfFrame(ps->frame, 0);
      if (mi < 0) continue;
      double T[16];
      rowMajor4x4(ps->T_map_base, T);
      machines[static_cast<std::size_t>(mi)].a.at("pose_T_map_base").append(T);
    } else if (const auto* ob = std::get_if<Observation>(&e)) {
      const auto it = machine_index.find(ob->machine_id);
      if (it == machine_index.end()) continue;
      MachineSets& M = machines[it->second];
      const MachineTruth& tr = sim.machineTruth(it->second);
      double T[16];
      M.a.at("stamp").append(&ob->stamp);
      rowMajor4x4(tr.T_map_base, T);
      M.a.at("T_map_base").append(T);
      M.a.at("twist_base").append(tr.twist_base.data());
      rowMajor4x4(tr.T_map_blade, T);
      M.a.at("T_map_blade").append(T);
      M.a.at("twist_blade").append(tr.twist_blade.data());
      M.a.at("cylinder_length_m").append(tr.cylinder_length_m.data());
      rowMajor4x4(ob->T_map_base, T);
      M.a.at("e_T_map_base").append(T);
      M.a.at("e_twist_base").append(ob->twist_base.data());
      rowMajor4x4(ob->T_map_blade, T);
      M.a.at("e_T_map_blade").append(T);
      M.a.at("e_twist_blade").append(ob->twist_blade.data());
      M.a.at("e_cylinder_length_m").append(ob->cylinder_length_m.data());
      double err[6];
      poseError(ob->T_map_base, tr.T_map_base, err);
      M.a.at("e_error_base").append(err);
      poseError(ob->T_map_blade, tr.T_map_blade, err);
      M.a.at("e_error_blade").append(err);
      M.a.at("cylinder_velocity_mps").append(ob->cylinder_velocity_mps.data());
      M.a.at("track_speed_mps").append(ob->track_speed_mps.data());
      M.a.at("engine_speed_rpm").append(&ob->engine_speed_rpm);
      M.a.at("action").append(ob->action.data());
      M.a.at("force_base_N").append(ob->force_base_N.data());
      M.a.at("t_force_map_N").append(tr.force_map_N.data());
      M.a.at("t_force_base_N").append(tr.force_base_N.data());
      M.a.at("t_force_quiet_map_N").append(tr.force_quiet_map_N.data());
      const double fee[6] = {tr.fee.alpha_rad, tr.fee.rho_rad, tr.fee.depth_m, tr.fee.width_m, tr.fee.q_n, tr.fee.beta_rad};
      M.a.at("t_fee").append(fee);
      const double soil[5] = {tr.fee.c_pa, tr.fee.phi_rad, tr.fee.gamma_n_m3, tr.fee.ca_pa, tr.fee.delta_rad};
      M.a.at("t_soil").append(soil);
      const std::uint8_t st = tr.stalled ? 1 : 0;
      M.a.at("t_stalled").append(&st);
      M.a.at("t_setpoints").append(tr.setpoints.data());
      M.a.at("t_cut").append(&tr.cut_bank_m3);
      if (tr.has_arm) {
        M.a.at("a_q").append(tr.arm_q.data());
        M.a.at("a_qd").append(tr.arm_qd.data());
        M.a.at("a_tau").append(tr.arm_torque_nm.data());
        M.a.at("a_qm").append(tr.arm_q_measured.data());
        M.a.at("a_lever").append(tr.arm_lever.data());
        // The steady-state rates the levers asked for (lever x max rate): what a replay in SI
        // units gives back.
        const ArmSpec& as = *sim.scenario().machines[it->second].arm;
        std::array<double, 4> cmd;
        for (int k = 0; k < 4; ++k) cmd[k] = tr.arm_lever[k] * as.joints[k].max_rate_rps;
        M.a.at("a_cmd").append(cmd.data());
        M.a.at("a_incl").append(tr.arm_inclination.data());
        M.a.at("a_inclm").append(tr.arm_inclination_measured.data());
        M.a.at("a_stalled").append(&tr.arm_stalled);
        const std::int32_t phase = tr.arm_phase;
        M.a.at("a_phase").append(&phase);
        rowMajor4x4(tr.T_map_bucket, T);
        M.a.at("a_T_bucket").append(T);
        M.a.at("a_force").append(tr.bucket_force_map_N.data());
        const double load[3] = {tr.bucket_load_kg, tr.bucket_load_m3, tr.bucket_bank_m3};
        M.a.at("a_load").append(load);
        const double moved[2] = {tr.bucket_dug_bank_m3, tr.bucket_dumped_bank_m3};
        M.a.at("a_moved").append(moved);
      }
    }
  }
  if (sim.time() + 1e-9 >= next_snapshot) {
    snapshot(sim);
    while (next_snapshot <= sim.time() + 1e-9) next_snapshot += snapshot_interval;
  }
}

void EpisodeWriter::close(const Simulator& sim) {
  Impl& I = *impl_;
  if (I.closed) return;
  using Clock = std::chrono::steady_clock;
  const auto seconds = [](Clock::time_point a, Clock::time_point b) { return std::chrono::duration<double>(b - a).count(); };
  const Clock::time_point t0 = Clock::now();
  if (std::abs(I.last_snapshot_t - sim.time()) > 1e-9) I.snapshot(sim);
  for (auto& m : I.machines) {
    for (auto& [k, a] : m.a) a.flush();
    for (auto& [k, c] : m.cloud) {
      c.stamp.flush(); c.T.flush(); c.offset.flush(); c.count.flush(); c.points.flush();
    }
    for (auto& [k, u] : m.imu) {
      u.stamp.flush(); u.accel.flush(); u.gyro.flush();
    }
  }
  I.snap_stamp.flush();
  // Summed over every node: done while the writer drains rather than after it.
  const double bank_final = sim.truth().bankVolume();
  I.writer.drain();  // the writer thread's last HDF5 call: from here on this thread makes them
  attrDouble(I.file, "lost_volume_m3", sim.truth().lostVolume());
  attrDouble(I.file, "compacted_volume_m3", sim.truth().compactedVolume());
  attrDouble(I.file, "bank_volume_final_m3", bank_final);
  const Clock::time_point t1 = Clock::now();
  I.closeAll();
  const Clock::time_point t2 = Clock::now();
  io::sealFile(I.tmp_path);
  std::error_code ec;
  fs::rename(I.tmp_path, I.final_path, ec);
  if (ec) throw OutputError(I.final_path + ": cannot rename the finished episode into place: " + ec.message());
  I.close_timing = {seconds(t0, t1), seconds(t1, t2), seconds(t2, Clock::now())};
  I.closed = true;
}

static_assert(sizeof(hid_t) == sizeof(std::int64_t), "EpisodeFile keeps a hid_t in an int64");

EpisodeFile::EpisodeFile(const std::string& path) : path_(path) {
  // A damaged file never reaches libhdf5, which can crash on one (io/file_seal.hpp).
  io::verifySeal(path);
  H5Eset_auto2(H5E_DEFAULT, nullptr, nullptr);
  file_ = H5Fopen(path.c_str(), H5F_ACC_RDONLY, H5P_DEFAULT);
  if (file_ < 0) throw InputError(path + ": cannot open as HDF5");
}

EpisodeFile::~EpisodeFile() {
  if (file_ >= 0) H5Fclose(file_);
}

std::vector<double> EpisodeFile::read(const std::string& dataset, std::vector<std::uint64_t>& dims) const {
  const hid_t ds = H5Dopen2(file_, dataset.c_str(), H5P_DEFAULT);
  if (ds < 0) throw InputError(path_ + ": no dataset '" + dataset + "'");
  const hid_t sp = H5Dget_space(ds);
  const int nd = H5Sget_simple_extent_ndims(sp);
  std::vector<hsize_t> d(static_cast<std::size_t>(std::max(nd, 0)));
  H5Sget_simple_extent_dims(sp, d.data(), nullptr);
  std::uint64_t n = 1;
  for (hsize_t x : d) n = saturatingProduct({n, static_cast<std::uint64_t>(x)});
  // A dataset can declare (chunked, compressed) far more elements than the file holds: refuse
  // before allocating what its header asks for.
  try {
    requireInputBudget(saturatingProduct({n, sizeof(double)}), path_ + ": dataset '" + dataset + "' of " +
                       std::to_string(n) + " values", "read as doubles");
  } catch (...) {
    H5Sclose(sp);
    H5Dclose(ds);
    throw;
  }
  std::vector<double> v(n);
  const herr_t rc = n ? H5Dread(ds, H5T_NATIVE_DOUBLE, H5S_ALL, H5S_ALL, H5P_DEFAULT, v.data()) : 0;
  H5Sclose(sp);
  H5Dclose(ds);
  if (rc < 0) throw InputError(path_ + ": cannot read dataset '" + dataset + "' as numbers");
  dims.assign(d.begin(), d.end());
  return v;
}

bool EpisodeFile::has(const std::string& dataset) const {
  // H5Lexists needs every group on the way to exist: test the path one component at a time.
  std::size_t pos = 0;
  while (pos < dataset.size()) {
    const std::size_t next = dataset.find('/', pos + 1);
    const std::string prefix = dataset.substr(0, next);
    if (!prefix.empty() && prefix != "/" && H5Lexists(file_, prefix.c_str(), H5P_DEFAULT) <= 0) return false;
    if (next == std::string::npos) break;
    pos = next;
  }
  return true;
}

std::string EpisodeFile::rootAttribute(const std::string& name) const {
  if (H5Aexists(file_, name.c_str()) <= 0) throw InputError(path_ + ": no attribute '" + name + "'");
  const hid_t a = H5Aopen(file_, name.c_str(), H5P_DEFAULT);
  const hid_t t = H5Aget_type(a);
  const std::size_t n = H5Tget_size(t);
  std::string s(n, '\0');
  const herr_t rc = H5Tget_class(t) == H5T_STRING ? H5Aread(a, t, s.data()) : -1;
  H5Tclose(t);
  H5Aclose(a);
  if (rc < 0) throw InputError(path_ + ": attribute '" + name + "' is not a string");
  s.erase(std::find(s.begin(), s.end(), '\0'), s.end());
  return s;
}

std::vector<double> readEpisodeDataset(const std::string& path, const std::string& dataset,
                                       std::vector<std::uint64_t>& dims) {
  return EpisodeFile(path).read(dataset, dims);
}

io::Trajectory episodeTrajectory(const EpisodeFile& file, const std::string& machine_id) {
  std::vector<std::uint64_t> dims;
  const std::string m = "/machines/" + machine_id;
  const std::vector<double> stamp = file.read(m + "/stamp", dims);
  const std::vector<double> T = file.read(m + "/T_map_base", dims);
  if (T.size() != 16 * stamp.size())
    throw InputError(file.path() + ": " + m + "/T_map_base does not hold one 4x4 matrix per stamp");
  std::vector<io::StampedPose> poses(stamp.size());
  for (std::size_t k = 0; k < stamp.size(); ++k) {
    poses[k].stamp = stamp[k];
    for (int r = 0; r < 3; ++r) {
      for (int c = 0; c < 3; ++c) poses[k].T_world_body.linear()(r, c) = T[16 * k + 4 * r + c];
      poses[k].T_world_body.translation()[r] = T[16 * k + 4 * r + 3];
    }
  }
  return io::Trajectory(std::move(poses), file.path() + " (" + m + "/T_map_base)");
}

std::string runEpisode(const Scenario& scenario, const std::string& dir, EpisodeOptions options,
                       EpisodeTiming* timing) {
  std::error_code ec;
  fs::create_directories(dir, ec);
  if (ec) throw OutputError(dir + ": cannot create the output folder: " + ec.message());
  const std::string path = (fs::path(dir) / "episode.h5").string();
  using Clock = std::chrono::steady_clock;
  const Clock::time_point t0 = Clock::now();
  Simulator sim(scenario);
  EpisodeWriter w(path, sim, options);
  const Clock::time_point t1 = Clock::now();
  std::vector<Event> ev;
  while (sim.next(ev)) {
    w.record(sim, std::move(ev));
    ev.clear();
  }
  const Clock::time_point t2 = Clock::now();
  w.close(sim);
  if (timing) {
    const Clock::time_point t3 = Clock::now();
    timing->setup_s = std::chrono::duration<double>(t1 - t0).count();
    timing->run_s = std::chrono::duration<double>(t3 - t1).count();
    timing->close_s = std::chrono::duration<double>(t3 - t2).count();
    timing->writer_cpu_s = w.writerCpuSeconds();
    timing->close_parts = w.closeTiming();
    timing->rays = sim.stats().rays;
    timing->rays_kept = sim.stats().rays_kept;
  }
  return path;
}

}  // namespace terramap::sim

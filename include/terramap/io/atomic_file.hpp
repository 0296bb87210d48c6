#pragma once
/// \file
/// Atomic file replacement: every terramap output (snapshot, GeoTIFF, PNG, reports) is first
/// written to `<target>.tmp.<pid>.<random>` in the *same folder* as the target, flushed to disk
/// (fsync), and then renamed over the target. rename(2) within one file system is atomic, so a
/// reader (or a crash, or a full disk) sees either the complete old file or the complete new
/// one, never a torn mix. The folder is fsync'ed after the rename (best effort) so the new
/// name survives a power cut.
///
/// On any failure the temporary file is removed, the target is left untouched and
/// terramap::OutputError is thrown with the target path and the errno text (strerror).
///
/// Threading: independent AtomicFile objects may be used concurrently (temporary names carry
/// the process id and 64 random bits; they are created with O_EXCL). One object is not
/// thread-safe.
#include <cstddef>
#include <cstdint>
#include <filesystem>
#include <functional>
#include <string>
#include <vector>

namespace terramap::io {

/// A file being written that replaces `target` only when commit() succeeds.
/// Destroying it without commit() removes the temporary file (the target is not touched).
class AtomicFile {
 public:
  /// Creates and opens the temporary file next to `target`.
  /// \throws OutputError if the folder does not exist or is not writable.
  explicit AtomicFile(std::filesystem::path target);
  ~AtomicFile();
  AtomicFile(const AtomicFile&) = delete;
  AtomicFile& operator=(const AtomicFile&) = delete;

  const std::filesystem::path& target() const { return target_; }
  const std::filesystem::path& tempPath() const { return temp_; }
  /// Bytes written so far.
  std::uint64_t size() const { return written_; }

  /// Appends bytes (buffered). \throws OutputError (e.g. ENOSPC), after which the object is
  /// aborted: the temporary file is gone and further calls throw.
  void write(const void* data, std::size_t n);
  /// Flushes, fsyncs, closes and renames over the target. \throws OutputError.
  void commit();
  /// Removes the temporary file now. Never throws; idempotent.
  void abort() noexcept;

 private:
  void flushBuffer();
  [[noreturn]] void fail(const std::string& what, int err);

  std::filesystem::path target_;
  std::filesystem::path temp_;
  int fd_ = -1;
  bool done_ = false;
  std::uint64_t written_ = 0;
  std::vector<unsigned char> buffer_;
};

/// Replaces `target` with `bytes` atomically. \throws OutputError.
void writeFileAtomically(const std::filesystem::path& target, const void* bytes, std::size_t n);
void writeFileAtomically(const std::filesystem::path& target, const std::string& bytes);

/// For writers that need a *path* rather than a stream (GDAL drivers): reserves a unique
/// temporary path next to `target` (the empty file is created with O_EXCL so no one else can
/// take the name), calls `produce(temp_path)` which must create/overwrite that file, then
/// fsyncs it and renames it over `target`. If `produce` throws, the temporary file (and any
/// `<temp>.aux.xml` side-car a GDAL driver may have left) is removed and the exception is
/// propagated unchanged. \throws OutputError for the file-system steps.
void replaceFileAtomically(const std::filesystem::path& target,
                           const std::function<void(const std::filesystem::path& temp_path)>& produce);

/// `<target>.tmp.<pid>.<16 hex digits>`: what AtomicFile uses (exposed for tests and tools that
/// sweep stale temporaries left by a killed process).
std::filesystem::path temporaryPathFor(const std::filesystem::path& target);

/// Removes from `folder` (not from folders below it) the temporaries of terramap writers whose
/// process no longer runs, as a kill -9 or a power cut leaves them: `<name>.tmp.<pid>.<16 hex
/// digits>` (AtomicFile) and `<name>.tmp-<pid>` (episodes). A file of a running process, or of
/// any other pattern, is left alone. Returns the removed paths; never throws.
std::vector<std::filesystem::path> removeStaleTemporaries(const std::filesystem::path& folder);

/// Creates `folder` if needed and a file in it (removed again), as every writer will: throws
/// OutputError naming the folder when that fails, so a run can refuse before it starts.
void requireWritableFolder(const std::filesystem::path& folder);

}  // namespace terramap::io

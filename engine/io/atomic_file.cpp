#include <terramap/core/error.hpp>
#include <terramap/io/atomic_file.hpp>

#include <algorithm>
#include <cctype>
#include <cerrno>
#include <cstdio>
#include <cstring>
#include <random>
#include <sstream>

#include <fcntl.h>
#include <signal.h>
#include <sys/stat.h>
#include <unistd.h>

namespace terramap::io {

namespace fs = std::filesystem;

namespace {

constexpr std::size_t kBufferBytes = std::size_t{1} << 20;

std::string errnoText(int err) { return std::strerror(err); }

std::string describe(const fs::path& target, const std::string& what, int err) {
  std::ostringstream os;
  os << "cannot write '" << target.string() << "': " << what;
  if (err != 0) os << ": " << errnoText(err);
  return os.str();
}

fs::path parentOf(const fs::path& p) {
  const fs::path parent = p.parent_path();
  return parent.empty() ? fs::path(".") : parent;
}

/// fsync on the folder makes the rename durable; some file systems refuse it (EINVAL), which is
/// harmless, so this is best effort.
void syncFolder(const fs::path& folder) {
  const int dfd = ::open(folder.c_str(), O_RDONLY | O_DIRECTORY | O_CLOEXEC);
  if (dfd < 0) return;
  (void)::fsync(dfd);
  ::close(dfd);
}

int createExclusive(const fs::path& target, fs::path& temp) {
  // A collision needs the same pid and 64 random bits; retry a few times anyway.
  for (int attempt = 0; attempt < 16; ++attempt) {
    temp = temporaryPathFor(target);
    const int fd = ::open(temp.c_str(), O_WRONLY | O_CREAT | O_EXCL | O_CLOEXEC, 0666);
    if (fd >= 0) return fd;
    if (errno != EEXIST) {
      const int err = errno;
      // The temporary name means nothing to the user; the folder it lives in is what is wrong.
      const fs::path folder = parentOf(target);
      std::error_code ec;
      if (err == ENOENT && !fs::exists(folder, ec))
        throw OutputError(describe(target, "folder '" + folder.string() + "' does not exist (create it first)", err));
      if (err == ENOTDIR)
        throw OutputError(describe(target, "'" + folder.string() + "' is not a folder", err));
      throw OutputError(describe(target, "cannot create a file in folder '" + folder.string() + "' (temporary '" +
                                             temp.filename().string() + "')", err));
    }
  }
  throw OutputError(describe(target, "no free temporary name after 16 attempts", 0));
}

void fsyncPath(const fs::path& target, const fs::path& temp) {
  const int fd = ::open(temp.c_str(), O_RDONLY | O_CLOEXEC);
  if (fd < 0) {
    const int err = errno;
    throw OutputError(describe(target, "cannot reopen temporary file '" + temp.string() + "'", err));
  }
  if (::fsync(fd) != 0) {
    const int err = errno;
    ::close(fd);
    throw OutputError(describe(target, "fsync of '" + temp.string() + "' failed", err));
  }
  ::close(fd);
}

void renameOver(const fs::path& target, const fs::path& temp) {
  if (::rename(temp.c_str(), target.c_str()) != 0) {
    const int err = errno;
    throw OutputError(describe(target, "cannot rename '" + temp.string() + "' over it", err));
  }
  syncFolder(parentOf(target));
}

void removeQuietly(const fs::path& p) {
  std::error_code ec;
  fs::remove(p, ec);
}

}  // namespace

fs::path temporaryPathFor(const fs::path& target) {
  // One generator per thread, seeded from random_device: names must differ across processes
  // and threads, not be reproducible (O_EXCL catches the astronomically rare clash).
  static thread_local std::mt19937_64 rng([] {
    std::random_device rd;
    return (static_cast<std::uint64_t>(rd()) << 32) ^ rd();
  }());
  char suffix[64];
  std::snprintf(suffix, sizeof suffix, ".tmp.%ld.%016llx", static_cast<long>(::getpid()),
                static_cast<unsigned long long>(rng()));
  fs::path p = target;
  p += suffix;
  return p;
}

namespace {

/// The process id in a writer's temporary name, or -1 when `name` is not one.
long temporaryOwner(const std::string& name) {
  auto digitsBetween = [&](std::size_t b, std::size_t e) {
    if (b >= e || e - b > 10) return -1L;
    for (std::size_t i = b; i < e; ++i)
      if (name[i] < '0' || name[i] > '9') return -1L;
    return std::stol(name.substr(b, e - b));
  };
  // <name>.tmp-<pid>
  if (const std::size_t t = name.rfind(".tmp-"); t != std::string::npos && t > 0) {
    const long pid = digitsBetween(t + 5, name.size());
    if (pid > 0) return pid;
  }
  // <name>.tmp.<pid>.<16 hex digits>
  if (name.size() < 17 || name[name.size() - 17] != '.') return -1;
  for (std::size_t i = name.size() - 16; i < name.size(); ++i)
    if (!std::isxdigit(static_cast<unsigned char>(name[i]))) return -1;
  const std::size_t dot = name.size() - 17;
  const std::size_t t = name.rfind(".tmp.", dot);
  if (t == std::string::npos || t == 0) return -1;
  return digitsBetween(t + 5, dot);
}

bool processIsGone(long pid) { return pid != ::getpid() && ::kill(static_cast<pid_t>(pid), 0) != 0 && errno == ESRCH; }

}  // namespace

std::vector<fs::path> removeStaleTemporaries(const fs::path& folder) {
  std::vector<fs::path> removed;
  std::error_code ec;
  for (fs::directory_iterator it(folder, ec), end; !ec && it != end; it.increment(ec)) {
    std::error_code sec;
    if (!it->is_regular_file(sec)) continue;
    const long pid = temporaryOwner(it->path().filename().string());
    if (pid > 0 && processIsGone(pid) && fs::remove(it->path(), sec)) removed.push_back(it->path());
  }
  std::sort(removed.begin(), removed.end());
  return removed;
}

void requireWritableFolder(const fs::path& folder) {
  std::error_code ec;
  fs::create_directories(folder, ec);
  if (ec) throw OutputError("cannot write to output folder '" + folder.string() + "': " + ec.message());
  AtomicFile probe(folder / ".terramap-write-check");  // what a writer does first; removed again
  probe.abort();
}

AtomicFile::AtomicFile(fs::path target) : target_(std::move(target)) {
  if (target_.empty()) throw OutputError("cannot write '': empty output path");
  fd_ = createExclusive(target_, temp_);
  buffer_.reserve(kBufferBytes);
}

AtomicFile::~AtomicFile() { abort(); }

void AtomicFile::fail(const std::string& what, int err) {
  abort();
  throw OutputError(describe(target_, what, err));
}

void AtomicFile::flushBuffer() {
  const unsigned char* p = buffer_.data();
  std::size_t left = buffer_.size();
  while (left > 0) {
    const ssize_t n = ::write(fd_, p, left);
    if (n < 0) {
      if (errno == EINTR) continue;
      const int err = errno;
      buffer_.clear();
      fail("write to '" + temp_.string() + "' failed", err);
    }
    p += n;
    left -= static_cast<std::size_t>(n);
  }
  buffer_.clear();
}

void AtomicFile::write(const void* data, std::size_t n) {
  if (done_) throw OutputError(describe(target_, "write after commit or abort", 0));
  const auto* p = static_cast<const unsigned char*>(data);
  while (n > 0) {
    const std::size_t room = kBufferBytes - buffer_.size();
    const std::size_t take = n < room ? n : room;
    buffer_.insert(buffer_.end(), p, p + take);
    p += take;
    n -= take;
    written_ += take;
    if (buffer_.size() == kBufferBytes) flushBuffer();
  }
}

void AtomicFile::commit() {
  if (done_) throw OutputError(describe(target_, "commit after commit or abort", 0));
  flushBuffer();
  if (::fsync(fd_) != 0) {
    const int err = errno;
    fail("fsync of '" + temp_.string() + "' failed", err);
  }
  const int fd = fd_;
  fd_ = -1;
  if (::close(fd) != 0) {
    const int err = errno;
    fail("close of '" + temp_.string() + "' failed", err);
  }
  if (::rename(temp_.c_str(), target_.c_str()) != 0) {
    const int err = errno;
    fail("cannot rename '" + temp_.string() + "' over it", err);
  }
  done_ = true;
  syncFolder(parentOf(target_));
}

void AtomicFile::abort() noexcept {
  if (done_) return;
  done_ = true;
  if (fd_ >= 0) {
    ::close(fd_);
    fd_ = -1;
  }
  ::unlink(temp_.c_str());
}

void writeFileAtomically(const fs::path& target, const void* bytes, std::size_t n) {
  AtomicFile f(target);
  f.write(bytes, n);
  f.commit();
}

void writeFileAtomically(const fs::path& target, const std::string& bytes) {
  writeFileAtomically(target, bytes.data(), bytes.size());
}

void replaceFileAtomically(const fs::path& target, const std::function<void(const fs::path&)>& produce) {
  if (target.empty()) throw OutputError("cannot write '': empty output path");
  fs::path temp;
  const int fd = createExclusive(target, temp);
  ::close(fd);
  fs::path side_car = temp;
  side_car += ".aux.xml";
  try {
    produce(temp);
    removeQuietly(side_car);  // a driver's PAM side-car would describe the temp name only
    struct stat st {};
    if (::stat(temp.c_str(), &st) != 0) {
      const int err = errno;
      throw OutputError(describe(target, "the writer left no file at '" + temp.string() + "'", err));
    }
    fsyncPath(target, temp);
    renameOver(target, temp);
  } catch (...) {
    removeQuietly(temp);
    removeQuietly(side_car);
    throw;
  }
}

}  // namespace terramap::io

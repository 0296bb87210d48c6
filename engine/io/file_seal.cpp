#include <terramap/core/error.hpp>
#include <terramap/io/file_seal.hpp>
#include <terramap/io/snapshot.hpp>

#include <algorithm>
#include <cerrno>
#include <cinttypes>
#include <cstdio>
#include <cstring>
#include <string>
#include <system_error>
#include <thread>
#include <vector>

#include <fcntl.h>
#include <sys/stat.h>
#include <unistd.h>

namespace terramap::io {

namespace fs = std::filesystem;

namespace {

constexpr char kSealTag[] = "terramap-seal 1\n";

/// An open descriptor that closes itself.
struct Fd {
  int fd = -1;
  ~Fd() {
    if (fd >= 0) ::close(fd);
  }
};

/// Reads exactly n bytes at `offset`; false at an early end of file, errno set on an error.
bool readAt(int fd, void* buf, std::size_t n, std::uint64_t offset) {
  auto* p = static_cast<unsigned char*>(buf);
  while (n > 0) {
    const ssize_t r = ::pread(fd, p, n, static_cast<off_t>(offset));
    if (r < 0) {
      if (errno == EINTR) continue;
      return false;
    }
    if (r == 0) {
      errno = 0;
      return false;
    }
    p += r;
    n -= static_cast<std::size_t>(r);
    offset += static_cast<std::uint64_t>(r);
  }
  return true;
}

/// CRC-64 of bytes [a, b) of `fd`, read in 1 MiB pieces.
bool crcOfRange(int fd, std::uint64_t a, std::uint64_t b, std::uint64_t& crc) {
  std::vector<unsigned char> buf(static_cast<std::size_t>(std::min<std::uint64_t>(std::uint64_t{1} << 20, b - a)));
  crc = 0;
  for (std::uint64_t at = a; at < b;) {
    const std::size_t n = static_cast<std::size_t>(std::min<std::uint64_t>(buf.size(), b - at));
    if (!readAt(fd, buf.data(), n, at)) return false;
    crc = crc64(buf.data(), n, crc);
    at += n;
  }
  return true;
}

/// CRC-64 of bytes [kSealBytes, size) of `fd`: a large file in up to four pieces read on their
/// own threads, combined with crc64Combine (an episode's seal, hundreds of MB, is on the critical
/// path of `terramap sim`, after the simulation, when the cores are free). Read with pread, not
/// mapped: a file cut short meanwhile is an error, not a SIGBUS.
bool crcAfterBlock(int fd, std::uint64_t size, std::uint64_t& crc) {
  crc = 0;
  if (size <= kSealBytes) return true;
  const std::uint64_t n = size - kSealBytes;
  // 8 MB a thread: a 2 s episode (32 MB) is sealed on both cores too, 12 -> 8 ms of its close
  // (`terramap sim configs/scenarios/bench_ctl_os1_64.yaml --duration 2`, its "checksum and
  // flush", medians of 9 runs; 32 MB a thread left such files to one).
  constexpr std::uint64_t kPerThread = std::uint64_t{8} << 20;
  const unsigned hw = std::max(1u, std::thread::hardware_concurrency());
  const std::size_t parts = static_cast<std::size_t>(std::clamp<std::uint64_t>(n / kPerThread, 1, std::min(hw, 4u)));
  std::vector<std::uint64_t> part_crc(parts, 0);
  std::vector<char> ok(parts, 0);
  std::vector<int> err(parts, 0);
  auto begin = [&](std::size_t p) { return kSealBytes + n * p / parts; };
  auto run = [&](std::size_t p) noexcept {
    try {
      ok[p] = crcOfRange(fd, begin(p), begin(p + 1), part_crc[p]);
      err[p] = errno;
    } catch (...) {  // the read buffer: nothing may escape a helper thread
      ok[p] = 0;
      err[p] = ENOMEM;
    }
  };
  std::vector<std::thread> helpers;
  helpers.reserve(parts);
  for (std::size_t p = 1; p < parts; ++p) {
    try {
      helpers.emplace_back(run, p);
    } catch (const std::system_error&) {
      run(p);  // no thread to be had: this part here
    }
  }
  run(0);
  for (std::thread& t : helpers) t.join();
  crc = part_crc[0];
  for (std::size_t p = 0; p < parts; ++p) {
    if (!ok[p]) {
      errno = err[p];
      return false;
    }
    if (p > 0) crc = crc64Combine(crc, part_crc[p], static_cast<std::size_t>(begin(p + 1) - begin(p)));
  }
  return true;
}

std::string errnoSuffix() { return errno ? std::string(": ") + std::strerror(errno) : std::string(); }

}  // namespace

void sealFile(const fs::path& path) {
  const std::string p = path.string();
  Fd f{::open(p.c_str(), O_RDWR | O_CLOEXEC)};
  if (f.fd < 0) throw OutputError(p + ": cannot open to seal" + errnoSuffix());
  struct stat st {};
  if (::fstat(f.fd, &st) != 0) throw OutputError(p + ": cannot stat to seal" + errnoSuffix());
  const auto size = static_cast<std::uint64_t>(st.st_size);
  if (size < kSealBytes) throw OutputError(p + ": " + std::to_string(size) + " bytes, shorter than the seal's block");
  unsigned char block[kSealBytes];
  if (!readAt(f.fd, block, sizeof block, 0)) throw OutputError(p + ": cannot read the seal's block" + errnoSuffix());
  // Sealing a file created without the user block would overwrite HDF5's superblock.
  if (std::any_of(block, block + sizeof block, [](unsigned char c) { return c != 0; }))
    throw OutputError(p + ": its first " + std::to_string(kSealBytes) +
                      " bytes are not an empty HDF5 user block (create the file with H5Pset_userblock)");
  // The data goes to disk while its checksum is computed, instead of after it; the final fsync
  // then covers only the seal block.
  int flush_rc = 0, flush_errno = 0;
  auto flush = [&]() noexcept {
    flush_rc = ::fdatasync(f.fd);
    flush_errno = errno;
  };
  std::thread flusher;
  try {
    flusher = std::thread(flush);
  } catch (const std::system_error&) {
    flush();  // no thread to be had: flush first, then read
  }
  std::uint64_t crc = 0;
  bool read_ok = false;
  try {
    read_ok = crcAfterBlock(f.fd, size, crc);
  } catch (...) {
    if (flusher.joinable()) flusher.join();
    throw;
  }
  const int read_errno = errno;
  if (flusher.joinable()) flusher.join();
  errno = read_errno;
  if (!read_ok) throw OutputError(p + ": cannot read the file to seal it" + errnoSuffix());
  errno = flush_errno;
  if (flush_rc != 0) throw OutputError(p + ": cannot flush the file to seal it" + errnoSuffix());
  char text[kSealBytes] = {};
  std::snprintf(text, sizeof text, "%sbytes %" PRIu64 "\ncrc64 %016" PRIx64 "\n", kSealTag, size, crc);
  for (std::size_t done = 0; done < sizeof text;) {
    const ssize_t w = ::pwrite(f.fd, text + done, sizeof text - done, static_cast<off_t>(done));
    if (w < 0 && errno == EINTR) continue;
    if (w <= 0) throw OutputError(p + ": cannot write the seal" + errnoSuffix());
    done += static_cast<std::size_t>(w);
  }
  if (::fsync(f.fd) != 0) throw OutputError(p + ": cannot flush the sealed file" + errnoSuffix());
}

void verifySeal(const fs::path& path) {
  const std::string p = path.string();
  Fd f{::open(p.c_str(), O_RDONLY | O_CLOEXEC)};
  if (f.fd < 0) throw InputError(p + ": cannot open" + errnoSuffix());
  struct stat st {};
  if (::fstat(f.fd, &st) != 0) throw InputError(p + ": cannot stat" + errnoSuffix());
  if (!S_ISREG(st.st_mode)) throw InputError(p + ": not a regular file");
  const auto size = static_cast<std::uint64_t>(st.st_size);
  const std::string unsealed =
      p + ": no terramap seal in its first " + std::to_string(kSealBytes) +
      " bytes: not written by terramap, or by one older than the seal (2026-11); simulate or generate it again "
      "(docs/sim.md, \"Episode layout\")";
  char block[kSealBytes + 1] = {};
  if (size < kSealBytes || !readAt(f.fd, block, kSealBytes, 0) ||
      std::strncmp(block, kSealTag, sizeof kSealTag - 1) != 0)
    throw InputError(unsealed);
  std::uint64_t want_size = 0, want_crc = 0;
  int used = 0;
  if (std::sscanf(block + sizeof kSealTag - 1, "bytes %" SCNu64 "\ncrc64 %16" SCNx64 "\n%n", &want_size, &want_crc,
                  &used) != 2 ||
      used == 0)
    throw InputError(p + ": its seal is damaged (cannot read the length and checksum in its first " +
                     std::to_string(kSealBytes) + " bytes)");
  if (want_size != size)
    throw InputError(p + ": " + std::to_string(size) + " bytes, but its seal says " + std::to_string(want_size) +
                     (size < want_size ? " (truncated)" : " (extended after it was written)"));
  std::uint64_t crc = 0;
  if (!crcAfterBlock(f.fd, size, crc)) throw InputError(p + ": cannot read" + errnoSuffix());
  if (crc != want_crc) {
    char hex[64];
    std::snprintf(hex, sizeof hex, "%016" PRIx64 " where its seal says %016" PRIx64, crc, want_crc);
    throw InputError(p + ": damaged: checksum (CRC-64) of its contents is " + hex);
  }
}

}  // namespace terramap::io

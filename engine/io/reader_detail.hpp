#pragma once
// Private helpers shared by the readers in engine/io (not installed).
#include <terramap/core/error.hpp>

#include <cstdint>
#include <cstdio>
#include <cstring>
#include <string>
#include <vector>

namespace terramap::io::detail {

/// Opens `path` for binary reading; InputError naming the file and errno text on failure.
std::FILE* openForRead(const std::string& path, const char* what);

/// Size of an open file in bytes (seeks to the end and back to the start).
std::uint64_t fileSize(std::FILE* f, const std::string& path);

/// Whole file into memory.
std::vector<unsigned char> readWholeFile(const std::string& path, const char* what);

/// Lower-case extension with the dot ("" if none).
std::string lowerExtension(const std::string& path);

/// RAII for std::FILE*.
struct FileCloser {
  std::FILE* f = nullptr;
  ~FileCloser() {
    if (f) std::fclose(f);
  }
};

/// Little-endian loads independent of host byte order and alignment.
inline std::uint16_t loadU16(const unsigned char* p) {
  return static_cast<std::uint16_t>(p[0] | (p[1] << 8));
}
inline std::uint32_t loadU32(const unsigned char* p) {
  return static_cast<std::uint32_t>(p[0]) | (static_cast<std::uint32_t>(p[1]) << 8) |
         (static_cast<std::uint32_t>(p[2]) << 16) | (static_cast<std::uint32_t>(p[3]) << 24);
}
inline std::uint64_t loadU64(const unsigned char* p) {
  return static_cast<std::uint64_t>(loadU32(p)) | (static_cast<std::uint64_t>(loadU32(p + 4)) << 32);
}
inline std::int32_t loadI32(const unsigned char* p) {
  const std::uint32_t u = loadU32(p);
  std::int32_t v;
  std::memcpy(&v, &u, 4);
  return v;
}
inline float loadF32(const unsigned char* p) {
  const std::uint32_t u = loadU32(p);
  float v;
  std::memcpy(&v, &u, 4);
  return v;
}
inline double loadF64(const unsigned char* p) {
  const std::uint64_t u = loadU64(p);
  double v;
  std::memcpy(&v, &u, 8);
  return v;
}

}  // namespace terramap::io::detail

#include "reader_detail.hpp"

#include <terramap/core/memory_budget.hpp>

#include <algorithm>
#include <cctype>
#include <cerrno>
#include <filesystem>

namespace terramap::io::detail {

std::FILE* openForRead(const std::string& path, const char* what) {
  std::FILE* f = std::fopen(path.c_str(), "rb");
  if (!f) {
    throw InputError(std::string("cannot open ") + what + " '" + path + "': " + std::strerror(errno));
  }
  // fopen succeeds on a directory on Linux; reading it then fails with EISDIR.
  std::error_code ec;
  if (std::filesystem::is_directory(path, ec)) {
    std::fclose(f);
    throw InputError(std::string("cannot open ") + what + " '" + path + "': is a directory");
  }
  return f;
}

std::uint64_t fileSize(std::FILE* f, const std::string& path) {
  if (std::fseek(f, 0, SEEK_END) != 0) throw InputError("cannot seek in '" + path + "': " + std::strerror(errno));
  const long size = std::ftell(f);
  if (size < 0) throw InputError("cannot tell the size of '" + path + "': " + std::strerror(errno));
  if (std::fseek(f, 0, SEEK_SET) != 0) throw InputError("cannot seek in '" + path + "': " + std::strerror(errno));
  return static_cast<std::uint64_t>(size);
}

std::vector<unsigned char> readWholeFile(const std::string& path, const char* what) {
  FileCloser fc{openForRead(path, what)};
  const std::uint64_t size = fileSize(fc.f, path);
  requireInputBudget(size, std::string(what) + " '" + path + "'", "the whole file in memory");
  std::vector<unsigned char> data(size);
  if (size != 0 && std::fread(data.data(), 1, size, fc.f) != size) {
    throw InputError("read error in '" + path + "' (expected " + std::to_string(size) + " bytes)");
  }
  return data;
}

std::string lowerExtension(const std::string& path) {
  std::string ext = std::filesystem::path(path).extension().string();
  std::transform(ext.begin(), ext.end(), ext.begin(), [](unsigned char c) { return static_cast<char>(std::tolower(c)); });
  return ext;
}

}  // namespace terramap::io::detail

#include "elf_section.hpp"

#include <elf.h>

#include <algorithm>
#include <cstdint>
#include <cstring>
#include <fstream>
#include <vector>

namespace terramap::detail {

namespace {

#if defined(__LP64__)
using Ehdr = Elf64_Ehdr;
using Shdr = Elf64_Shdr;
using Sym = Elf64_Sym;
#define TERRAMAP_ST_BIND ELF64_ST_BIND
constexpr unsigned char kClass = ELFCLASS64;
#else
using Ehdr = Elf32_Ehdr;
using Shdr = Elf32_Shdr;
using Sym = Elf32_Sym;
#define TERRAMAP_ST_BIND ELF32_ST_BIND
constexpr unsigned char kClass = ELFCLASS32;
#endif
#if __BYTE_ORDER__ == __ORDER_LITTLE_ENDIAN__
constexpr unsigned char kData = ELFDATA2LSB;
#else
constexpr unsigned char kData = ELFDATA2MSB;
#endif

bool readAt(std::ifstream& f, std::uint64_t offset, std::uint64_t file_size, void* dst, std::size_t n) {
  if (offset > file_size || n > file_size - offset) return false;
  f.seekg(static_cast<std::streamoff>(offset));
  f.read(static_cast<char*>(dst), static_cast<std::streamsize>(n));
  return static_cast<std::size_t>(f.gcount()) == n;
}

/// The section table of an ELF file of this machine's class and byte order.
bool readSectionTable(std::ifstream& f, std::uint64_t& file_size, std::vector<Shdr>& sections, Ehdr& eh) {
  f.seekg(0, std::ios::end);
  const auto end = f.tellg();
  if (end <= 0) return false;
  file_size = static_cast<std::uint64_t>(end);
  if (!readAt(f, 0, file_size, &eh, sizeof eh)) return false;
  if (std::memcmp(eh.e_ident, ELFMAG, SELFMAG) != 0 || eh.e_ident[EI_CLASS] != kClass ||
      eh.e_ident[EI_DATA] != kData || eh.e_shentsize != sizeof(Shdr) || eh.e_shnum == 0 ||
      eh.e_shstrndx >= eh.e_shnum)
    return false;
  sections.resize(eh.e_shnum);
  return readAt(f, eh.e_shoff, file_size, sections.data(), sizeof(Shdr) * sections.size());
}

}  // namespace

std::optional<std::vector<std::string>> readElfExportedSymbols(const std::string& path) {
  // A plugin's own table is small; a larger one is refused rather than read (libraries that
  // big are not plugins, and the bound keeps a crafted header from costing memory).
  constexpr std::uint64_t kMaxTableBytes = 64u << 20;
  std::ifstream f(path, std::ios::binary);
  if (!f) return std::nullopt;
  std::uint64_t file_size = 0;
  std::vector<Shdr> sections;
  Ehdr eh{};
  if (!readSectionTable(f, file_size, sections, eh)) return std::nullopt;
  for (const Shdr& s : sections) {
    if (s.sh_type != SHT_DYNSYM) continue;
    if (s.sh_link >= sections.size() || s.sh_entsize != sizeof(Sym) || s.sh_size > kMaxTableBytes) return std::nullopt;
    const Shdr& str = sections[s.sh_link];
    if (str.sh_type != SHT_STRTAB || str.sh_size > kMaxTableBytes) return std::nullopt;
    std::vector<Sym> syms(s.sh_size / sizeof(Sym));
    std::string names(str.sh_size, '\0');
    if (!readAt(f, s.sh_offset, file_size, syms.data(), syms.size() * sizeof(Sym)) ||
        !readAt(f, str.sh_offset, file_size, names.data(), names.size()))
      return std::nullopt;
    std::vector<std::string> out;
    for (const Sym& y : syms) {
      const unsigned bind = TERRAMAP_ST_BIND(y.st_info);
      if (y.st_shndx == SHN_UNDEF || y.st_name >= names.size() || (bind != STB_GLOBAL && bind != STB_WEAK)) continue;
      out.emplace_back(names.c_str() + y.st_name, strnlen(names.c_str() + y.st_name, names.size() - y.st_name));
    }
    std::sort(out.begin(), out.end());
    return out;
  }
  return std::nullopt;
}

std::optional<std::string> readElfSection(const std::string& path, const std::string& name,
                                          std::size_t max_bytes) {
  std::ifstream f(path, std::ios::binary | std::ios::ate);
  if (!f) return std::nullopt;
  const auto end = f.tellg();
  if (end <= 0) return std::nullopt;
  const auto file_size = static_cast<std::uint64_t>(end);

  Ehdr eh{};
  if (!readAt(f, 0, file_size, &eh, sizeof eh)) return std::nullopt;
  if (std::memcmp(eh.e_ident, ELFMAG, SELFMAG) != 0 || eh.e_ident[EI_CLASS] != kClass ||
      eh.e_ident[EI_DATA] != kData || eh.e_shentsize != sizeof(Shdr) || eh.e_shnum == 0 ||
      eh.e_shstrndx >= eh.e_shnum)
    return std::nullopt;

  std::vector<Shdr> sections(eh.e_shnum);
  if (!readAt(f, eh.e_shoff, file_size, sections.data(), sizeof(Shdr) * sections.size()))
    return std::nullopt;
  const Shdr& names = sections[eh.e_shstrndx];
  if (names.sh_size > (1u << 20)) return std::nullopt;
  std::string strtab(names.sh_size, '\0');
  if (!readAt(f, names.sh_offset, file_size, strtab.data(), strtab.size())) return std::nullopt;

  for (const Shdr& s : sections) {
    if (s.sh_name >= strtab.size() || s.sh_type == SHT_NOBITS) continue;
    // strtab entries are NUL-terminated; compare up to the NUL within the table
    const char* n = strtab.c_str() + s.sh_name;
    if (std::strncmp(n, name.c_str(), strtab.size() - s.sh_name) != 0 ||
        std::strlen(n) != name.size())
      continue;
    const std::size_t size = static_cast<std::size_t>(std::min<std::uint64_t>(s.sh_size, max_bytes));
    std::string bytes(size, '\0');
    if (!readAt(f, s.sh_offset, file_size, bytes.data(), size)) return std::nullopt;
    return bytes;
  }
  return std::nullopt;
}

}  // namespace terramap::detail

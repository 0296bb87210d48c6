#pragma once
// Reads one section of an ELF file without loading it, so a plugin's ABI note can be checked
// before dlopen() runs any of the plugin's code (static constructors built with other flags,
// a sanitizer runtime that aborts the process when it is not loaded first).
#include <optional>
#include <string>
#include <vector>

namespace terramap::detail {

/// The bytes of section `name` of the ELF file at `path`, at most `max_bytes` of them.
/// nullopt when the file cannot be read, is not an ELF file of this machine's class and byte
/// order, or has no such section (the caller then leaves the verdict to the dynamic loader).
/// Never throws for bad file content: every offset is checked against the file size.
std::optional<std::string> readElfSection(const std::string& path, const std::string& name,
                                          std::size_t max_bytes = 4096);

/// The names of the symbols the ELF file at `path` exports (defined, global or weak, in its
/// dynamic symbol table), sorted: what dlopen()/dlsym() would find, read without loading.
/// nullopt under the same conditions as readElfSection() or without a dynamic symbol table.
std::optional<std::vector<std::string>> readElfExportedSymbols(const std::string& path);

}  // namespace terramap::detail

#pragma once
/// \file
/// The binary contract between the host and a plugin library.
///
/// A plugin library exports three `extern "C"` symbols (TERRAMAP_PLUGIN emits them):
///   const terramap_plugin_info_t terramap_plugin_info;   // the info record
///   terramap::Plugin* terramap_plugin_create();           // new instance (caller owns)
///   void terramap_plugin_destroy(terramap::Plugin*);      // deletes it inside the library
/// The host reads the fingerprint from the file's TERRAMAP_PLUGIN_ABI_SECTION before loading
/// it, then the record before anything else, and refuses the library, naming the file, the
/// expected and the found value, if `abi_version`, `info_size` or `fingerprint` differ from its
/// own. `abi_version` and `info_size` come first and never move, so any future record can be
/// refused safely.
///
/// Memory rule of the boundary: nothing the host hands a plugin (and nothing a plugin hands
/// the host) is freed by the other side's allocator, except through std containers of types
/// that are not over-aligned (both sides use the one global operator new/delete). Owning Eigen
/// objects never cross: LayeredMap copies into and out of caller-owned buffers, records travel
/// in shared_ptr whose deleter is the publisher's.
#include <terramap/plugin/plugin.hpp>

#include <Eigen/Core>
#include <cstdint>

/// Bump when Plugin, ProcessContext, LayeredMap, events or the record layout change.
/// 2: LayeredMap hands out no owning Eigen object (readLayer/writeLayer; toMatrix is inline and
///    local to the caller); the fingerprint pins Eigen's alignment and names the sanitizers.
/// 3: Params carries reported problems and the map geometry, ProcessContext a ChangeTracker,
///    LayeredMap per-tile write counters.
/// 4: the Event variant gained ImuSample (EventKind::Imu).
/// 5: the Event variant gained JointState (EventKind::JointState).
/// 6: JointState carries the four link frames (T_map_link).
#define TERRAMAP_PLUGIN_ABI_VERSION 6u

#define TERRAMAP_STR_(x) #x
#define TERRAMAP_STR(x) TERRAMAP_STR_(x)
#if defined(__clang__)
#define TERRAMAP_COMPILER_ID "clang-" TERRAMAP_STR(__clang_major__)
#elif defined(__GNUC__)
#define TERRAMAP_COMPILER_ID "gcc-" TERRAMAP_STR(__GNUC__)
#else
#define TERRAMAP_COMPILER_ID "unknown"
#endif
#ifndef _GLIBCXX_USE_CXX11_ABI
#define _GLIBCXX_USE_CXX11_ABI 0
#endif
// Sanitizers: an instrumented plugin in an uninstrumented host aborts inside dlopen (the
// runtime must come first), and AddressSanitizer switches Eigen to its hand-made aligned
// allocator. GCC defines __SANITIZE_*__; clang answers __has_feature.
#if defined(__SANITIZE_ADDRESS__)
#define TERRAMAP_ABI_ASAN "1"
#elif defined(__has_feature)
#if __has_feature(address_sanitizer)
#define TERRAMAP_ABI_ASAN "1"
#endif
#endif
#ifndef TERRAMAP_ABI_ASAN
#define TERRAMAP_ABI_ASAN "0"
#endif
#if defined(__SANITIZE_THREAD__)
#define TERRAMAP_ABI_TSAN "1"
#elif defined(__has_feature)
#if __has_feature(thread_sanitizer)
#define TERRAMAP_ABI_TSAN "1"
#endif
#endif
#ifndef TERRAMAP_ABI_TSAN
#define TERRAMAP_ABI_TSAN "0"
#endif
// libstdc++'s debug mode changes the layout of every std container.
#if defined(_GLIBCXX_DEBUG)
#define TERRAMAP_ABI_GLIBCXX_DEBUG "1"
#else
#define TERRAMAP_ABI_GLIBCXX_DEBUG "0"
#endif
/// What must match for C++ types to be shared across the boundary, as `key-value` fields
/// separated by ';':
/// - `terramap-M.m`: terramap's major.minor;
/// - the compiler family and major version, and the libstdc++ string ABI (`cxx11abi`);
/// - `eigen-X.Y.Z`: Eigen's version (events and records hold Eigen types);
/// - `eigen-align-A-S`: EIGEN_MAX_ALIGN_BYTES and EIGEN_MAX_STATIC_ALIGN_BYTES. SIMD flags
///   (-mavx, -march=native) raise both unless pinned, which moves members of events and
///   records (Isometry3d becomes 32- or 64-byte aligned). The CMake package pins both to 16 on
///   every target that links terramap::core. Eigen's *heap* alignment still follows the CPU
///   target (it cannot be pinned), so its allocator differs between such builds: that is why no
///   owning Eigen object crosses the boundary (see "Memory rule of the boundary" above);
/// - `asan`, `tsan`: built with AddressSanitizer / ThreadSanitizer;
/// - `glibcxx-debug`: built with _GLIBCXX_DEBUG.
/// docs/plugins.md lists the flags a plugin may differ in.
#define TERRAMAP_BUILD_FINGERPRINT                                                       \
  "terramap-0.1;" TERRAMAP_COMPILER_ID ";cxx11abi-" TERRAMAP_STR(_GLIBCXX_USE_CXX11_ABI)     \
  ";eigen-" TERRAMAP_STR(EIGEN_WORLD_VERSION) "." TERRAMAP_STR(EIGEN_MAJOR_VERSION) "."     \
  TERRAMAP_STR(EIGEN_MINOR_VERSION)                                                         \
  ";eigen-align-" TERRAMAP_STR(EIGEN_MAX_ALIGN_BYTES) "-" TERRAMAP_STR(EIGEN_MAX_STATIC_ALIGN_BYTES) \
  ";asan-" TERRAMAP_ABI_ASAN ";tsan-" TERRAMAP_ABI_TSAN ";glibcxx-debug-" TERRAMAP_ABI_GLIBCXX_DEBUG

/// ELF section that holds a copy of the fingerprint (NUL-terminated). The host reads it from
/// the file *before* loading the library, so a plugin built with other flags is refused before
/// any of its code (static constructors, a sanitizer runtime) runs.
#define TERRAMAP_PLUGIN_ABI_SECTION ".terramap_abi"

extern "C" {
/// The info record. Plain C layout.
struct terramap_plugin_info_t {
  std::uint32_t abi_version;   ///< TERRAMAP_PLUGIN_ABI_VERSION the plugin was built with
  std::uint32_t info_size;     ///< sizeof(terramap_plugin_info_t) in the plugin
  const char* fingerprint;     ///< TERRAMAP_BUILD_FINGERPRINT in the plugin
  const char* name;            ///< plugin type, as written in `type:` of the pipeline YAML
  const char* version;         ///< the plugin's own version
  const char* description;     ///< one line for `terramap plugins`
};
/// Declared here so every definition has external linkage (a namespace-scope const would
/// otherwise be internal and the host would not find it).
__attribute__((visibility("default"))) extern const terramap_plugin_info_t terramap_plugin_info;
}

namespace terramap {
constexpr const char* kPluginInfoSymbol = "terramap_plugin_info";
constexpr const char* kPluginCreateSymbol = "terramap_plugin_create";
constexpr const char* kPluginDestroySymbol = "terramap_plugin_destroy";
}  // namespace terramap

/// Exports `Class` as plugin type `name_literal` (a string literal, snake_case).
/// Use once per library, at namespace scope:
///   TERRAMAP_PLUGIN(terramap::plugins::SmoothFilter, "smooth_filter", "1.0.0", "Gaussian smoothing")
/// The record's fingerprint points into TERRAMAP_PLUGIN_ABI_SECTION, which keeps the section
/// referenced (a linker's --gc-sections cannot drop it).
#define TERRAMAP_PLUGIN(Class, name_literal, version_literal, description_literal)             \
  extern "C" {                                                                                 \
  __attribute__((used, section(TERRAMAP_PLUGIN_ABI_SECTION))) static const char                \
      terramap_plugin_abi_note[] = TERRAMAP_BUILD_FINGERPRINT;                                 \
  const terramap_plugin_info_t terramap_plugin_info = {                                        \
      TERRAMAP_PLUGIN_ABI_VERSION,                                                             \
      static_cast<std::uint32_t>(sizeof(terramap_plugin_info_t)),                              \
      terramap_plugin_abi_note,                                                                \
      name_literal,                                                                            \
      version_literal,                                                                         \
      description_literal};                                                                    \
  __attribute__((visibility("default"))) terramap::Plugin* terramap_plugin_create() {          \
    return new Class();                                                                        \
  }                                                                                            \
  __attribute__((visibility("default"))) void terramap_plugin_destroy(terramap::Plugin* p) {   \
    delete p;                                                                                  \
  }                                                                                            \
  }

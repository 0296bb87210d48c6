#pragma once
/// \file
/// The binary contract between the host and a plugin library.
///
/// A plugin library exports three `extern "C"` symbols (TERRAMAP_PLUGIN emits them):
///   const terramap_plugin_info_t terramap_plugin_info;   // the info record
///   terramap::Plugin* terramap_plugin_create();           // new instance (caller owns)
///   void terramap_plugin_destroy(terramap::Plugin*);      // deletes it inside the library
/// The host reads the record before anything else and refuses the library, naming the file,
/// the expected and the found value, if `abi_version`, `info_size` or `fingerprint` differ
/// from its own. `abi_version` and `info_size` come first and never move, so any future
/// record can be refused safely.
#include <terramap/plugin/plugin.hpp>

#include <Eigen/Core>
#include <cstdint>

/// Bump when Plugin, ProcessContext, LayeredMap, events or the record layout change.
#define TERRAMAP_PLUGIN_ABI_VERSION 1u

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
/// What must match for C++ types to be shared across the boundary: the compiler family and
/// major version, the libstdc++ string ABI, Eigen's version (events hold Eigen types) and
/// terramap's major.minor.
#define TERRAMAP_BUILD_FINGERPRINT                                                   \
  "terramap-0.1;" TERRAMAP_COMPILER_ID ";cxx11abi-" TERRAMAP_STR(_GLIBCXX_USE_CXX11_ABI) \
  ";eigen-" TERRAMAP_STR(EIGEN_WORLD_VERSION) "." TERRAMAP_STR(EIGEN_MAJOR_VERSION) "." \
  TERRAMAP_STR(EIGEN_MINOR_VERSION)

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
#define TERRAMAP_PLUGIN(Class, name_literal, version_literal, description_literal)             \
  extern "C" {                                                                                 \
  const terramap_plugin_info_t terramap_plugin_info = {                                        \
      TERRAMAP_PLUGIN_ABI_VERSION,                                                             \
      static_cast<std::uint32_t>(sizeof(terramap_plugin_info_t)),                              \
      TERRAMAP_BUILD_FINGERPRINT,                                                              \
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

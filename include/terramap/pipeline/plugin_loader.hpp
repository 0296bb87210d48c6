#pragma once
/// \file
/// Finding and loading plugin libraries (Boost.DLL).
///
/// Search order for a plugin type `T`: the file `T.so` in (1) the paths given to the
/// registry (YAML `plugin_paths`, see forPipeline()), (2) the folders given on the command line
/// (addTrustedPaths(), `--plugin-path`), (3) each entry of the environment variable
/// TERRAMAP_PLUGIN_PATH (colon-separated), (4) `<dir of libterramap_pipeline.so>/terramap/plugins`
/// (the build tree and the install tree have the same layout). The first file found wins.
///
/// Trust (docs/reliability.md, "What a config file can make terramap do"): loading a library
/// runs its code. A pipeline file's `plugin_paths` are used only when the user allowed it
/// (allowConfigPluginPaths(), `--allow-config-plugin-paths`); forPipeline() refuses them
/// otherwise. Listing the types for a did-you-mean reads the files and loads none, and so does
/// describe(), which `terramap validate` checks stages with (the description each plugin's
/// build embedded in its file, plugin_schema.hpp).
///
/// Before creating anything the loader checks, in this order, and refuses with a PluginError
/// naming the file, the expected and the found value, *from the file, before loading it* (so
/// none of its code runs): it is an ELF shared library of this machine whose section table can
/// be read; it exports `terramap_plugin_info`; the build fingerprint in its `.terramap_abi`
/// section (a plugin built with other flags or a sanitizer never runs); it exports
/// `terramap_plugin_create` and `terramap_plugin_destroy`. Then, loaded: the library loads; loading it left the floating-point environment
/// (rounding, x86 MXCSR flush-to-zero) as it was (restored and refused otherwise: -ffast-math);
/// it exports `terramap_plugin_info`; its `abi_version`; its `info_size`; its build fingerprint
/// (again, for libraries without the section); it exports `terramap_plugin_create` and
/// `terramap_plugin_destroy`; its `name` equals `T`. A fingerprint refusal names each
/// differing field and its likely cause (abi.hpp lists the fields).
/// A loaded library stays loaded as long as any plugin created from it lives.
#include <terramap/pipeline/plugin_schema.hpp>
#include <terramap/plugin/abi.hpp>
#include <terramap/plugin/plugin.hpp>

#include <memory>
#include <string>
#include <vector>

namespace terramap {

class PluginLibrary;  // opaque: a loaded, checked shared library

/// Owns one plugin instance and keeps its library loaded. Destroys the instance inside the
/// library that created it.
class TERRAMAP_API PluginHandle {
 public:
  PluginHandle() = default;
  PluginHandle(std::shared_ptr<PluginLibrary> lib, Plugin* p);
  PluginHandle(PluginHandle&&) noexcept;
  PluginHandle& operator=(PluginHandle&&) noexcept;
  PluginHandle(const PluginHandle&) = delete;
  PluginHandle& operator=(const PluginHandle&) = delete;
  ~PluginHandle();

  Plugin* get() const { return plugin_; }
  Plugin* operator->() const { return plugin_; }
  explicit operator bool() const { return plugin_ != nullptr; }
  const std::string& type() const;
  const std::string& path() const;
  const std::string& version() const;

 private:
  void reset();
  std::shared_ptr<PluginLibrary> lib_;
  Plugin* plugin_ = nullptr;
};

/// One library found on the search path, and whether it was accepted.
struct PluginCandidate {
  std::string path;
  bool ok = false;
  std::string type, version, description;  ///< from the record when it could be read
  std::string reason;                      ///< why it was refused
};

/// What the file of a plugin type tells without loading it (PluginRegistry::describe()).
struct PluginFileDescription {
  std::string path;
  std::optional<PluginDescription> description;  ///< its embedded schema, when it has one of this build
  std::string missing;  ///< why there is none (no section, unreadable, another build's)
};

class TERRAMAP_API PluginRegistry {
 public:
  /// \param extra_paths searched first (e.g. the pipeline's plugin_paths).
  explicit PluginRegistry(std::vector<std::string> extra_paths = {});
  /// The registry of a pipeline file whose `plugin_paths` are `config_paths` (at `where`,
  /// "file:line:col"). \throws ConfigError when it names folders and they are not allowed.
  static PluginRegistry forPipeline(const std::vector<std::string>& config_paths, const std::string& where);
  /// Whether forPipeline() accepts a file's plugin_paths (default false). Thread-safe.
  static void allowConfigPluginPaths(bool allow);
  static bool configPluginPathsAllowed();
  /// Folders the user named (`--plugin-path`), searched by every registry made after this.
  static void addTrustedPaths(const std::vector<std::string>& dirs);
  const std::vector<std::string>& searchPaths() const { return paths_; }
  /// The default plugin folder next to libterramap_pipeline.so.
  static std::string defaultPluginDir();

  /// Every `*.so` on the search path, loaded and checked (refused ones with the reason).
  std::vector<PluginCandidate> scan() const;
  /// Names of the plugin types on the search path, from the files alone (nothing is loaded):
  /// each `T.so` that passes the checks made before loading.
  std::vector<std::string> availableTypes() const;
  /// Path of `type.so` on the search path, or "" if none.
  std::string find(const std::string& type) const;

  /// The embedded description of `type` (plugin_schema.hpp), read from its file after the
  /// checks made before loading; nothing is loaded. \throws PluginError: unknown type (with
  /// did-you-mean), a library refused from its file, or a description of another plugin type.
  PluginFileDescription describe(const std::string& type) const;
  /// Creates a plugin of `type`. \throws PluginError: unknown type (with did-you-mean and the
  /// searched folders) or a refused library.
  PluginHandle create(const std::string& type) const;
  /// Loads a specific library file and creates its plugin; `expected_type` empty = any.
  static PluginHandle createFromFile(const std::string& path, const std::string& expected_type = {});

 private:
  std::string findOrThrow(const std::string& type) const;
  std::vector<std::string> paths_;
};

}  // namespace terramap

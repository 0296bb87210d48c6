#pragma once
/// \file
/// A plugin's description as data: its parameters and the layers it reads, writes and creates
/// as a function of those parameters, so `terramap validate` can check a pipeline against a
/// plugin without loading it (loading a library runs its code).
///
/// How it gets into the plugin: terramap_add_plugin() runs `terramap-plugin-schema` on the
/// module right after linking it (building already trusts the code). The tool loads the plugin,
/// asks schema(), configures it with its defaults and with probe values of each parameter, and
/// derives from what layers() answers a description (describePlugin()), which it writes as JSON
/// into the module's ELF section TERRAMAP_PLUGIN_SCHEMA_SECTION. The JSON holds the module's
/// GNU build-id, so a description copied into another build is recognised and not believed.
///
/// What the description covers: every parameter's type, default, range, choices, list size and
/// unit; layer names built from string parameters ("{input_layer}", "{soil_prefix}c") and layers
/// present only when a string parameter is not empty. A parameter whose other values changed the
/// layer set in any other way is listed in `layers_vary_with`: a pipeline that sets it to another
/// value than the probe's gets "layers unknown" for that stage, not a guess; for a bool or a
/// string of choices the layers at each other value are kept instead (`variants`), as long as
/// only one such parameter differs from the probe. Not covered: the
/// plugin's own cross-parameter checks in configure() (they need its code).
#include <terramap/core/error.hpp>
#include <terramap/plugin/params.hpp>
#include <terramap/plugin/plugin.hpp>

#include <map>
#include <optional>
#include <string>
#include <variant>
#include <vector>

/// The ELF section of a plugin module that holds its description (JSON, UTF-8, no NUL).
#define TERRAMAP_PLUGIN_SCHEMA_SECTION ".terramap_schema"

namespace terramap {

/// One layer of a description: its name is a sequence of literal text and parameter values.
struct LayerTemplate {
  struct Part {
    std::string text;   ///< literal text, or the parameter's name when `is_param`
    bool is_param = false;
  };
  std::vector<Part> name;
  LayerAccess access = LayerAccess::Read;
  std::string unit;
  /// String parameters that must be non-empty for the layer to exist (an optional input).
  std::vector<std::string> unless_empty;
};

struct PluginDescription {
  static constexpr int kFormat = 1;
  std::string type, version;
  std::string build_id;  ///< hex of the module's NT_GNU_BUILD_ID note descriptor
  ParamSchema params;
  /// The parameter values the layers were probed at (defaults and the build's probe values).
  std::map<std::string, ParamValue> probe;
  std::vector<LayerTemplate> layers;
  /// The layers where one parameter of few values (a bool, a string of choices) has another
  /// value than the probe's, all others as probed: another layer set (an optional output).
  struct Variant {
    std::string param;
    ParamValue value;
    std::vector<LayerTemplate> layers;
  };
  std::vector<Variant> variants;
  std::vector<std::string> layers_vary_with;
};

/// The JSON text of a description (what goes into the section).
TERRAMAP_API std::string descriptionToJson(const PluginDescription& d);
/// Parses what descriptionToJson() wrote. \throws InputError naming `what` (the file) and the
/// first field that is missing or of the wrong type; never anything else for bad text.
TERRAMAP_API PluginDescription descriptionFromJson(const std::string& json, const std::string& what);

/// Loads the plugin module at `path` (runs its code: build time only), probes it and returns its
/// description. `probe_values` ("KEY=VALUE", YAML scalar or flow list syntax as in `--set`)
/// configure parameters that have no default or whose default does not configure.
/// \throws PluginError when the module is refused or its configure() refuses the probe values.
TERRAMAP_API PluginDescription describePlugin(const std::string& path, const std::vector<std::string>& probe_values);

/// The layers of a stage whose checked parameter values are `values` (defaults filled in), or
/// nullopt with `why` when the description cannot tell (a parameter of `layers_vary_with` set
/// to another value than the probe's, two parameters with variants both set to other values, or
/// a name built from a parameter that has no value).
TERRAMAP_API std::optional<std::vector<LayerSpec>> layersFromDescription(
    const PluginDescription& d, const std::map<std::string, ParamValue>& values, std::string& why);

/// The hex build-id of the ELF file at `path` ("" when it has none or cannot be read).
TERRAMAP_API std::string elfBuildId(const std::string& path);

}  // namespace terramap

#pragma once
/// \file
/// The YAML pipeline, parsed and checked for structure (no plugin loaded yet).
///
/// ```yaml
/// version: 1
/// map: {resolution: 0.05, size: [400, 400], center: [0, 0], tile: 64, sparse: false,
///       layers: [{name: elevation, unit: m}]}      # optional layers that exist from the start
/// threads: 2
/// plugin_paths: [build/lib/terramap/plugins]     # optional, searched before the defaults
/// source: {type: sequence, ...}                   # what produces events (see source.hpp)
/// pipeline:
///   - {name: lidar, type: lidar_fusion, params: {...}}
/// outputs: {dir: out/demo, geotiff: [elevation], png: [elevation], snapshot: true,
///           mcap: {layers: [elevation], topic: /terramap/grid_map, copy_clouds: false}}
/// ```
/// Relative paths in the file are resolved against the file's folder.
#include <terramap/core/geometry.hpp>
#include <terramap/core/layered_map.hpp>
#include <terramap/plugin/params.hpp>

#include <map>
#include <string>
#include <vector>

namespace terramap {

/// A parameter value as written in YAML, with its location for messages.
struct RawParam {
  ParamValue value;
  std::string where;  ///< "file:line:col: key.path"
  bool is_map = false;  ///< a nested mapping (never valid as a plugin param value)
};

struct LayerDecl {
  std::string name, unit;
  float fill = std::numeric_limits<float>::quiet_NaN();
  std::string where;
};

struct StageSpec {
  std::string name, type;
  std::string where;       ///< location of the stage entry
  std::string type_where;  ///< location of its `type:` value
  std::map<std::string, RawParam> params;
};

/// A source's settings, kept loose: each source type validates its own keys
/// (source.hpp) with the same file:line:col messages.
struct SourceSpec {
  std::string type = "none";
  std::string where;
  std::map<std::string, RawParam> settings;
};

/// `outputs.mcap`: the map as grid_map_msgs/msg/GridMap in a ROS 2 MCAP file
/// (io/gridmap_mcap.hpp, docs/ros2.md), one message per `every` clouds and one after the run.
struct McapOutputSpec {
  bool enabled = false;
  std::vector<std::string> layers;  ///< written layers, in this order (required)
  std::string file = "map.mcap";    ///< in outputs.dir
  std::string topic = "/terramap/grid_map";
  std::string frame_id = "map";
  bool copy_clouds = false;         ///< also the clouds (and their poses on /tf)
  std::string cloud_topic = "/terramap/points";
  std::string compression = "zstd";  ///< zstd, lz4 or none
  int every = 1;                     ///< a map message after every this many clouds
  std::string where;
};

struct OutputSpec {
  std::string dir = "out";
  std::vector<std::string> geotiff;  ///< layers, one band each
  std::vector<std::string> png;      ///< layers; {"all"} = every layer
  bool png_all = false;
  bool snapshot = true;
  bool report = true;
  int epsg = 0;                      ///< 0 = local metric CRS
  std::vector<double> origin;        ///< easting, northing of the map frame origin (with epsg)
  /// report.json's "series": one entry per this many seconds of event time (0 = none): events,
  /// drops, records, allocated tiles, the map's centre, resident memory and, when the source knows the truth, the
  /// map's error against it at that moment (docs/reliability.md, "Soak").
  double series_interval_s = 0.0;
  McapOutputSpec mcap;
  std::string where;
};

struct PipelineSpec {
  std::string file;  ///< path it was read from ("<string>" for text)
  std::string base_dir;
  int version = 1;
  double resolution = 0.05;
  Size size{400, 400};
  Position center = Position::Zero();
  MapOptions map_options;
  std::vector<LayerDecl> layers;
  int threads = 2;
  std::vector<std::string> plugin_paths;
  std::string plugin_paths_where;  ///< "file:line:col: plugin_paths" when given
  SourceSpec source;
  std::vector<StageSpec> stages;
  OutputSpec outputs;

  Geometry geometry() const { return Geometry(resolution, size, center); }
  /// A path from the file, made absolute against base_dir.
  std::string resolvePath(const std::string& p) const;
};

/// Parses and checks the structure. Collects every problem it can find (unknown keys with
/// did-you-mean, wrong types, out-of-range values, duplicate stage names) and throws one
/// ConfigError listing them all, one per line, each "file:line:col: key.path: message".
TERRAMAP_API PipelineSpec parsePipelineFile(const std::string& path);
TERRAMAP_API PipelineSpec parsePipelineString(const std::string& yaml, const std::string& name = "<string>",
                                             const std::string& base_dir = ".");

/// Sets stage parameters from the command line (`terramap run --set`): each override is
/// "STAGE.KEY=VALUE", STAGE a stage's `name`, VALUE read as a YAML value the way `params:` reads
/// it (0.5, 3, true, none, [1, 2], "quoted text"). The value replaces the file's (or adds the
/// key); the stage's declared params check it later (Engine::validate), and their messages name
/// the override ("--set bayes.prior=nonee: ..."). Every malformed override is reported at once.
/// \throws ConfigError listing the overrides without '=', without a "STAGE." prefix, naming no
///         stage of the pipeline, or whose value is not a scalar or a list of scalars.
TERRAMAP_API void applyParamOverrides(PipelineSpec& spec, const std::vector<std::string>& overrides);

}  // namespace terramap

#pragma once
/// \file
/// Colour renders of map layers (PNG via GDAL), for eyes rather than for GIS.
///
/// Orientation is the GeoTIFF's (geotiff.hpp): north up, image row 0 = largest map y, image
/// column 0 = smallest map x, so a PNG and a GeoTIFF of the same map overlay pixel for pixel
/// (times `scale`).
///
/// Colour pipeline for each cell value v:
///   1. v is NaN (unknown) -> `nan_color` (transparent by default). +-inf clamp to the ends.
///   2. t = (v - min) / (max - min) clamped to [0, 1] ([min, max] fixed or robust percentiles
///      of the finite values; a degenerate range maps everything to t = 0.5).
///   3. colour = colormap(t): linear interpolation in sRGB between a few control points.
///   4. hillshade (optional): colour *= ambient + (1 - ambient) * shade, shade in [0, 1] from
///      Horn's gradients (see hillshade()).
///   5. each cell becomes a `scale` x `scale` block of pixels (nearest neighbour).
/// Channels are rounded to nearest (half away from zero) 8-bit values. Rendering is serial and
/// deterministic; it reads the map through const accessors (do not mutate it meanwhile).
#include <terramap/core/layered_map.hpp>
#include <terramap/io/geotiff.hpp>

#include <array>
#include <cstdint>
#include <filesystem>
#include <optional>
#include <string>
#include <vector>

namespace terramap::io {

struct Rgba {
  std::uint8_t r = 0, g = 0, b = 0, a = 255;
  bool operator==(const Rgba& o) const { return r == o.r && g == o.g && b == o.b && a == o.a; }
  bool operator!=(const Rgba& o) const { return !(*this == o); }
};

/// A colour ramp given by control points at increasing t in [0, 1] (first at 0, last at 1).
class Colormap {
 public:
  struct Stop {
    double t;
    double r, g, b;  ///< 0..255
  };
  Colormap(std::string name, std::vector<Stop> stops, bool diverging);

  /// Built-in maps: "viridis" (perceptually uniform, default), "rdbu" (diverging red-white-blue,
  /// low = red; for errors and differences), "rdbu_r" (reversed), "grey" / "gray" (black to
  /// white). Names are case-insensitive.
  /// \throws ConfigError naming the unknown map, with did-you-mean and the list of names.
  static Colormap byName(const std::string& name);
  static std::vector<std::string> names();

  const std::string& name() const { return name_; }
  /// Diverging maps centre their automatic range on 0 (see RenderOptions::symmetric_auto_range).
  bool diverging() const { return diverging_; }
  /// Colour at t (clamped to [0, 1]; NaN -> t = 0), as unrounded 0..255 channels.
  std::array<double, 3> colourAt(double t) const;
  /// colourAt rounded to 8 bits, opaque.
  Rgba at(double t) const;

 private:
  std::string name_;
  std::vector<Stop> stops_;
  bool diverging_;
};

struct ValueRange {
  float min = 0.f, max = 1.f;
};

struct RenderOptions {
  std::string colormap = "viridis";
  /// Fixed value range; when absent, the robust range of the layer (percentiles below).
  std::optional<ValueRange> range;
  double low_percentile = 2.0;    ///< of the finite values, in [0, 100)
  double high_percentile = 98.0;  ///< in (low_percentile, 100]
  /// For diverging colormaps with an automatic range: use [-m, m], m = max(|lo|, |hi|), so
  /// white means exactly 0 (an error map reads "no error" at a glance).
  bool symmetric_auto_range = true;
  Rgba nan_color{0, 0, 0, 0};     ///< unknown cells; e.g. {128, 128, 128, 255} for opaque grey

  bool hillshade = false;         ///< shade the layer as elevation (metres, same frame as x/y)
  double azimuth_deg = 315.0;     ///< light from, clockwise from north (315 = north-west)
  double altitude_deg = 45.0;     ///< light elevation above the horizon, (0, 90]
  double z_factor = 1.0;          ///< vertical exaggeration, > 0
  double ambient = 0.0;           ///< shade floor in [0, 1): 0 = pure multiply

  int scale = 1;                  ///< pixels per cell edge, 1..64 (nearest upsampling)
};

/// An RGBA8 image, row-major, row 0 at the top.
struct Image {
  int width = 0, height = 0;
  std::vector<std::uint8_t> rgba;  ///< 4 bytes per pixel
  /// \throws std::out_of_range outside the image (a programming error, not user input).
  Rgba pixel(int row, int col) const;
};

/// Linear-interpolated percentiles (numpy's default "linear" method) of the finite values of
/// layer `id`; {0, 1} if it has none. \throws ConfigError on percentiles outside [0, 100] or
/// low >= high; LayerError on a bad id.
ValueRange robustRange(const LayeredMap& map, LayerId id, double low_percentile = 2.0,
                       double high_percentile = 98.0);

/// Hillshade of elevation layer `id` in north-up raster order (geotiff.hpp): shade = max(0,
/// n . l) with n the unit surface normal from Horn's 3x3 gradients
///   dz/dE = ((c + 2f + i) - (a + 2d + g)) / (8 res),  dz/dN = ((a + 2b + c) - (g + 2h + i)) / (8 res)
/// (a b c / d e f / g h i = the window, north row first) scaled by z_factor, and l the unit
/// vector towards the light (azimuth clockwise from north, altitude above the horizon).
/// A neighbour that is unknown (NaN) or off the map is mirrored through the centre
/// (2e - opposite); if that is unknown too, an edge neighbour becomes e and a diagonal one is
/// completed as on a plane from its two edge neighbours. So planes shade exactly up to the
/// edges and corners, and a hole does not disturb its neighbours' gradients much.
/// NaN where the cell itself is unknown.
/// \throws ConfigError on altitude outside (0, 90], non-finite azimuth, z_factor <= 0.
RasterF hillshade(const LayeredMap& map, LayerId id, double azimuth_deg = 315.0, double altitude_deg = 45.0,
                  double z_factor = 1.0);

/// Renders layer `layer`. \throws LayerError (unknown layer, did-you-mean), ConfigError (bad
/// colormap, range with min >= max or non-finite, percentiles, scale, hillshade parameters,
/// or an image over 2^28 pixels).
Image renderLayer(const LayeredMap& map, const std::string& layer, const RenderOptions& options = {});

/// The value range renderLayer maps to the colour ramp: options.range, or the robust range
/// (made symmetric for diverging maps). \throws ConfigError as renderLayer.
ValueRange renderRange(const LayeredMap& map, LayerId id, const RenderOptions& options);

/// Writes an RGBA PNG through GDAL's PNG driver, atomically. \throws OutputError.
void writePng(const Image& image, const std::filesystem::path& path);

/// Draws, onto `map_image` (renderLayer's output for `map` at `scale` pixels per cell), the
/// boundaries of the regions of a categorical layer `regions` (e.g. `truth_soil_zone`): every
/// pixel edge between two cells whose finite values differ gets `colour` on both sides (a line
/// two pixels wide at scale >= 2, one cell wide at scale 1). NaN cells are no region.
/// \throws LayerError if `regions` is not a layer of `map`; std::invalid_argument if the image is
/// not W·scale x H·scale.
void outlineRegions(Image& map_image, const LayeredMap& map, const std::string& regions, int scale, Rgba colour);

/// What makes a picture explain itself (annotate()).
struct Annotation {
  std::string title;    ///< first line; empty = "<layer> [<display unit>]"
  std::string caption;  ///< optional second line (e.g. the error statistics of the picture)
  /// Colour-bar labels show value * display_scale in display_unit; empty unit = displayUnit().
  double display_scale = 0.0;  ///< 0 = from displayUnit()
  std::string display_unit;
  /// A categorical layer (e.g. regions): labelled swatches instead of a colour bar.
  std::vector<std::pair<float, std::string>> categories;
  /// When not empty: a categorical layer whose region boundaries are drawn over the picture
  /// (outlineRegions), e.g. `truth_soil_zone` over a soil layer; the caption says so.
  std::string outline_regions;
  Rgba outline_colour{255, 255, 255, 255};
  /// Names of `outline_regions`' values, written on the map in each region (at its northmost
  /// row, in the middle of that row's cells of the region); values without a name are not labelled.
  std::vector<std::pair<float, std::string>> region_names;
};

/// The unit a colour bar (and the default title) shows a layer in: errors and differences in
/// metres (diverging colour maps) read in centimetres, newtons in kN, pascals in kPa, radians in
/// degrees; everything else in its own unit. Returns {unit, scale}.
std::pair<std::string, double> displayUnit(const std::string& unit, bool diverging);

/// Where annotate() put things, for tests and for callers that overlay more.
struct AnnotatedLayout {
  int map_x = 0, map_y = 0;          ///< top-left pixel of the map image in the canvas
  int bar_x = 0, bar_y = 0, bar_height = 0;  ///< colour bar (top = range max); 0 height if none
  int scale_bar_x = 0, scale_bar_y = 0, scale_bar_px = 0;  ///< left end, row, length
  double scale_bar_m = 0;            ///< the length it stands for
  /// The colour bar's arrow ends: values above its top / below its bottom exist (drawn in the
  /// end colour); the subtitle then gives the layer's whole range.
  bool arrow_above = false, arrow_below = false;
  std::vector<std::string> texts;    ///< every text drawn (title, subtitles, labels), in order
};

/// Puts `map_image` (renderLayer's output for `layer` with `options`) on a white canvas with a
/// title (layer and unit; no unit for a categorical layer) and optional caption, a colour bar
/// whose labels are in the display unit (symmetric around 0 for diverging maps, as the range is)
/// or, for a categorical layer (Annotation::categories), a swatch per category with its name; a
/// swatch for unknown cells when they are drawn opaque; map coordinates in metres along the
/// bottom (x) and left (y) edges; a scale bar in metres labelled at each tick. When finite
/// values lie outside the rendered range, the colour bar gets an arrow end (a triangle in the
/// end colour) on that side and a subtitle gives the layer's whole range. Text is drawn with FreeType from
/// DejaVu Sans (fonts-dejavu-core; TERRAMAP_FONT overrides the file).
/// \throws OutputError naming the font file when it cannot be loaded; ConfigError as renderLayer.
Image annotate(const Image& map_image, const LayeredMap& map, const std::string& layer, const RenderOptions& options,
               const Annotation& annotation, AnnotatedLayout* layout = nullptr);

/// renderLayer, then annotate() when `annotation` is given (the value range is resolved once for
/// both); without it, the picture is pixel for pixel the layer (it overlays the GeoTIFF).
Image renderPicture(const LayeredMap& map, const std::string& layer, const RenderOptions& options,
                    const std::optional<Annotation>& annotation);

/// renderPicture + writePng.
void renderPng(const LayeredMap& map, const std::string& layer, const std::filesystem::path& path,
               const RenderOptions& options = {}, const std::optional<Annotation>& annotation = std::nullopt);

}  // namespace terramap::io

#include <terramap/core/error.hpp>
#include <terramap/core/memory_budget.hpp>
#include <terramap/io/output_budget.hpp>

#include <algorithm>

namespace terramap::io {

namespace {
std::uint64_t cellsOf(const Geometry& g) {
  return saturatingProduct({static_cast<std::uint64_t>(g.size().x()), static_cast<std::uint64_t>(g.size().y())});
}
std::uint64_t saturatingSum(std::uint64_t a, std::uint64_t b) { return a > UINT64_MAX - b ? UINT64_MAX : a + b; }
}  // namespace

std::uint64_t geotiffWorkingBytes(const Geometry& g) { return saturatingProduct({cellsOf(g), 2, sizeof(float)}); }

std::uint64_t pngWorkingBytes(const Geometry& g, int scale) {
  const auto s = static_cast<std::uint64_t>(std::max(1, scale));
  const std::uint64_t pixels = saturatingProduct({cellsOf(g), s, s});
  // Four float copies of the layer; the picture and the canvas it is drawn on, 4 bytes a pixel.
  return saturatingSum(saturatingProduct({cellsOf(g), 4, sizeof(float)}), saturatingProduct({pixels, 2, 4}));
}

int runPngScale(const Geometry& g) { return std::max(1, 800 / std::max(g.size().x(), g.size().y())); }

void requireRasterOutputBudget(const Geometry& g, const std::string& format, int png_scale, const std::string& context,
                               bool from_file) {
  const std::string dims = std::to_string(g.size().x()) + " x " + std::to_string(g.size().y()) + " cells";
  const std::string what = context + ": writing a " + (format == "png" ? "PNG" : "GeoTIFF") + " of " + dims;
  const std::uint64_t bytes = format == "png" ? pngWorkingBytes(g, png_scale) : geotiffWorkingBytes(g);
  const std::string detail = "the whole raster of one layer, even of a sparse map";
  if (from_file) requireInputBudget(bytes, what, detail);
  else requireConfigBudget(bytes, what, detail);
  if (format == "png") {
    const auto s = static_cast<std::uint64_t>(std::max(1, png_scale));
    const std::uint64_t pixels = saturatingProduct({cellsOf(g), s, s});
    if (pixels > (std::uint64_t{1} << 28)) {
      const std::string msg = what + " at " + std::to_string(s) + " pixels per cell needs " + std::to_string(pixels) +
                              " pixels, more than a PNG render's 2^28 (write a GeoTIFF, or a smaller map)";
      if (from_file) throw InputError(msg);
      throw ConfigError(msg);
    }
  }
}

}  // namespace terramap::io

#pragma once
/// \file
/// What writing a map as a raster costs, checked against the memory budget before anything
/// runs (docs/reliability.md, "The memory budget"). A sparse map of 100000 x 100000 cells holds
/// only the tiles that were written, but its GeoTIFF band or PNG picture is the whole raster:
/// without this check a run would validate, play every event and then fail at the end.
#include <terramap/core/export.hpp>
#include <terramap/core/geometry.hpp>

#include <cstdint>
#include <string>

namespace terramap::io {

/// Memory taken while one layer is written as a GeoTIFF band: the layer as a matrix and its
/// north-up copy (bands are written one at a time).
TERRAMAP_API std::uint64_t geotiffWorkingBytes(const Geometry& g);
/// Memory taken while one layer is rendered as a PNG at `scale` pixels per cell edge: the
/// values, the range statistics' copy, the hillshade, and the RGBA picture with its annotated
/// canvas.
TERRAMAP_API std::uint64_t pngWorkingBytes(const Geometry& g, int scale);
/// Pixels per cell edge of the PNGs `terramap run` writes (about 800 pixels a side).
TERRAMAP_API int runPngScale(const Geometry& g);

/// Throws when writing a `format` ("geotiff" or "png") raster of `g` would exceed the budget
/// (or a PNG the renderer's 2^28-pixel limit): a ConfigError when the sizes come from a
/// configuration, an InputError when they come from a file (`from_file`). `context` names the
/// file and the key or layer.
TERRAMAP_API void requireRasterOutputBudget(const Geometry& g, const std::string& format, int png_scale,
                                            const std::string& context, bool from_file);

}  // namespace terramap::io

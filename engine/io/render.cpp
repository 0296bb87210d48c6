#include "gdal_support.hpp"

#include <terramap/core/error.hpp>
#include <terramap/core/text.hpp>
#include <terramap/io/atomic_file.hpp>
#include <terramap/io/render.hpp>

#include <algorithm>
#include <cctype>
#include <cmath>
#include <limits>
#include <memory>
#include <sstream>
#include <stdexcept>

namespace terramap::io {

namespace fs = std::filesystem;

namespace {

constexpr double kPi = 3.14159265358979323846;

std::string lower(std::string s) {
  for (auto& ch : s) ch = static_cast<char>(std::tolower(static_cast<unsigned char>(ch)));
  return s;
}

/// Control points from the published definitions: viridis at t = k/8 (van der Walt & Smith's
/// colormap, its commonly quoted 9-step hex values), RdBu = ColorBrewer's 11-class RdBu.
/// Linear interpolation between them is within a few 8-bit steps of the 256-entry originals.
std::vector<Colormap::Stop> hexStops(const std::vector<unsigned>& hex) {
  std::vector<Colormap::Stop> s;
  const double n = static_cast<double>(hex.size() - 1);
  for (std::size_t k = 0; k < hex.size(); ++k)
    s.push_back({static_cast<double>(k) / n, static_cast<double>((hex[k] >> 16) & 0xFF),
                 static_cast<double>((hex[k] >> 8) & 0xFF), static_cast<double>(hex[k] & 0xFF)});
  return s;
}

const std::vector<unsigned> kViridis = {0x440154, 0x472D7B, 0x3B528B, 0x2C728E, 0x21918C,
                                        0x28AE80, 0x5EC962, 0xADDC30, 0xFDE725};
const std::vector<unsigned> kRdBu = {0x67001F, 0xB2182B, 0xD6604D, 0xF4A582, 0xFDDBC7, 0xF7F7F7,
                                     0xD1E5F0, 0x92C5DE, 0x4393C3, 0x2166AC, 0x053061};

std::uint8_t to8(double v) {
  const double c = std::min(255.0, std::max(0.0, v));
  return static_cast<std::uint8_t>(std::lround(c));
}

}  // namespace

// ---- colormaps --------------------------------------------------------------------------------

Colormap::Colormap(std::string name, std::vector<Stop> stops, bool diverging)
    : name_(std::move(name)), stops_(std::move(stops)), diverging_(diverging) {
  TERRAMAP_CHECK(stops_.size() >= 2 && stops_.front().t == 0.0 && stops_.back().t == 1.0,
                 "colormap '" + name_ + "' needs stops at t = 0 and t = 1");
  for (std::size_t k = 1; k < stops_.size(); ++k)
    TERRAMAP_CHECK(stops_[k].t > stops_[k - 1].t, "colormap '" + name_ + "' stops must increase");
}

std::vector<std::string> Colormap::names() { return {"viridis", "rdbu", "rdbu_r", "grey", "gray"}; }

Colormap Colormap::byName(const std::string& name) {
  const std::string n = lower(name);
  if (n == "viridis") return Colormap("viridis", hexStops(kViridis), false);
  if (n == "rdbu") return Colormap("rdbu", hexStops(kRdBu), true);
  if (n == "rdbu_r") {
    std::vector<unsigned> r(kRdBu.rbegin(), kRdBu.rend());
    return Colormap("rdbu_r", hexStops(r), true);
  }
  if (n == "grey" || n == "gray") return Colormap("grey", {{0.0, 0, 0, 0}, {1.0, 255, 255, 255}}, false);
  throw ConfigError("unknown colormap '" + name + "'" + didYouMean(n, names()) + "; known: " + joinStrings(names()));
}

std::array<double, 3> Colormap::colourAt(double t) const {
  if (!(t > 0.0)) t = 0.0;  // also NaN
  if (t > 1.0) t = 1.0;
  // First stop whose t is >= the query; interpolate from the one before.
  auto hi = std::lower_bound(stops_.begin(), stops_.end(), t, [](const Stop& s, double v) { return s.t < v; });
  if (hi == stops_.begin()) return {hi->r, hi->g, hi->b};
  const auto lo = hi - 1;
  const double u = (t - lo->t) / (hi->t - lo->t);
  return {lo->r + (hi->r - lo->r) * u, lo->g + (hi->g - lo->g) * u, lo->b + (hi->b - lo->b) * u};
}

Rgba Colormap::at(double t) const {
  const auto c = colourAt(t);
  return Rgba{to8(c[0]), to8(c[1]), to8(c[2]), 255};
}

Rgba Image::pixel(int row, int col) const {
  if (row < 0 || col < 0 || row >= height || col >= width)
    throw std::out_of_range("pixel (" + std::to_string(row) + ", " + std::to_string(col) + ") outside a " +
                            std::to_string(width) + "x" + std::to_string(height) + " image");
  const std::size_t o = (static_cast<std::size_t>(row) * static_cast<std::size_t>(width) + static_cast<std::size_t>(col)) * 4;
  return Rgba{rgba[o], rgba[o + 1], rgba[o + 2], rgba[o + 3]};
}

// ---- value range ------------------------------------------------------------------------------

ValueRange robustRange(const LayeredMap& map, LayerId id, double low_percentile, double high_percentile) {
  if (!(low_percentile >= 0.0) || !(high_percentile <= 100.0) || !(low_percentile < high_percentile)) {
    std::ostringstream os;
    os << "percentiles must satisfy 0 <= low < high <= 100 (got " << low_percentile << ", " << high_percentile << ")";
    throw ConfigError(os.str());
  }
  const Eigen::MatrixXf m = map.toMatrix(id);
  std::vector<float> v;
  v.reserve(static_cast<std::size_t>(m.size()));
  for (Eigen::Index k = 0; k < m.size(); ++k)
    if (std::isfinite(m.data()[k])) v.push_back(m.data()[k]);
  if (v.empty()) return ValueRange{0.f, 1.f};
  auto pct = [&](double p) {
    const double pos = p / 100.0 * static_cast<double>(v.size() - 1);
    const std::size_t k = static_cast<std::size_t>(std::floor(pos));
    std::nth_element(v.begin(), v.begin() + static_cast<long>(k), v.end());
    const double a = v[k];
    if (k + 1 >= v.size()) return a;
    // The (k+1)-th order statistic is the minimum of the part after k.
    const double b = *std::min_element(v.begin() + static_cast<long>(k) + 1, v.end());
    return a + (b - a) * (pos - static_cast<double>(k));
  };
  const double lo = pct(low_percentile);
  const double hi = pct(high_percentile);
  return ValueRange{static_cast<float>(lo), static_cast<float>(hi)};
}

// ---- hillshade --------------------------------------------------------------------------------

RasterF hillshade(const LayeredMap& map, LayerId id, double azimuth_deg, double altitude_deg, double z_factor) {
  if (!std::isfinite(azimuth_deg)) throw ConfigError("hillshade azimuth must be finite");
  if (!(altitude_deg > 0.0 && altitude_deg <= 90.0)) {
    std::ostringstream os;
    os << "hillshade altitude must be in (0, 90] degrees (got " << altitude_deg << ")";
    throw ConfigError(os.str());
  }
  if (!(z_factor > 0.0) || !std::isfinite(z_factor)) {
    std::ostringstream os;
    os << "hillshade z factor must be a finite number > 0 (got " << z_factor << ")";
    throw ConfigError(os.str());
  }
  const RasterF z = northUpRaster(map, id);
  const double res = map.geometry().resolution();
  const double az = azimuth_deg * kPi / 180.0, alt = altitude_deg * kPi / 180.0;
  const double lx = std::sin(az) * std::cos(alt), ly = std::cos(az) * std::cos(alt), lz = std::sin(alt);
  const int H = static_cast<int>(z.rows()), W = static_cast<int>(z.cols());
  RasterF out(H, W);
  auto get = [&](int r, int c) -> double {
    if (r < 0 || c < 0 || r >= H || c >= W) return std::numeric_limits<double>::quiet_NaN();
    return z(r, c);
  };
  for (int r = 0; r < H; ++r) {
    for (int c = 0; c < W; ++c) {
      const double e = z(r, c);
      if (!std::isfinite(e)) {
        out(r, c) = std::numeric_limits<float>::quiet_NaN();
        continue;
      }
      // A missing neighbour (unknown or off the map) is mirrored through the centre
      // (2e - opposite); failing that, an edge neighbour becomes e and a diagonal one is
      // completed from its two edge neighbours as on a plane (N + E - e). A plane thus shades
      // exactly up to the map's edges and corners.
      auto edge = [&](int dr, int dc) {
        const double v = get(r + dr, c + dc);
        if (std::isfinite(v)) return v;
        const double o = get(r - dr, c - dc);
        return std::isfinite(o) ? 2.0 * e - o : e;
      };
      const double b = edge(-1, 0), d = edge(0, -1), f = edge(0, 1), h = edge(1, 0);
      auto diag = [&](int dr, int dc) {
        const double v = get(r + dr, c + dc);
        if (std::isfinite(v)) return v;
        const double o = get(r - dr, c - dc);
        if (std::isfinite(o)) return 2.0 * e - o;
        return (dr < 0 ? b : h) + (dc < 0 ? d : f) - e;
      };
      const double a = diag(-1, -1), cc = diag(-1, 1), g = diag(1, -1), i = diag(1, 1);
      const double dzde = ((cc + 2 * f + i) - (a + 2 * d + g)) / (8.0 * res) * z_factor;
      const double dzdn = ((a + 2 * b + cc) - (g + 2 * h + i)) / (8.0 * res) * z_factor;
      const double dot = (-dzde * lx - dzdn * ly + lz) / std::sqrt(1.0 + dzde * dzde + dzdn * dzdn);
      out(r, c) = static_cast<float>(std::max(0.0, dot));
    }
  }
  return out;
}

// ---- render -----------------------------------------------------------------------------------

ValueRange renderRange(const LayeredMap& map, LayerId id, const RenderOptions& o) {
  ValueRange range;
  if (o.range) {
    range = *o.range;
    if (!std::isfinite(range.min) || !std::isfinite(range.max) || !(range.min < range.max)) {
      std::ostringstream os;
      os << "render range must be finite with min < max (got " << range.min << ", " << range.max << ")";
      throw ConfigError(os.str());
    }
    return range;
  }
  range = robustRange(map, id, o.low_percentile, o.high_percentile);
  if (Colormap::byName(o.colormap).diverging() && o.symmetric_auto_range) {
    const float m = std::max(std::abs(range.min), std::abs(range.max));
    range = m > 0.f ? ValueRange{-m, m} : ValueRange{-1.f, 1.f};
  }
  return range;
}

Image renderLayer(const LayeredMap& map, const std::string& layer, const RenderOptions& o) {
  const LayerId id = map.layerId(layer);
  const Colormap cmap = Colormap::byName(o.colormap);
  if (o.scale < 1 || o.scale > 64) throw ConfigError("render scale must be in [1, 64] (got " + std::to_string(o.scale) + ")");
  if (!(o.ambient >= 0.0 && o.ambient < 1.0)) throw ConfigError("hillshade ambient must be in [0, 1)");
  const long W = map.geometry().size().x(), H = map.geometry().size().y();
  if (W * o.scale * H * o.scale > (1L << 28))
    throw ConfigError("render of " + std::to_string(W) + "x" + std::to_string(H) + " cells at scale " +
                      std::to_string(o.scale) + " exceeds 2^28 pixels; lower --scale");
  const ValueRange range = renderRange(map, id, o);
  const RasterF values = northUpRaster(map, id);
  RasterF shade;
  if (o.hillshade) shade = hillshade(map, id, o.azimuth_deg, o.altitude_deg, o.z_factor);

  const int S = o.scale;
  Image img;
  img.width = static_cast<int>(W) * S;
  img.height = static_cast<int>(H) * S;
  img.rgba.resize(static_cast<std::size_t>(img.width) * static_cast<std::size_t>(img.height) * 4);
  const double span = static_cast<double>(range.max) - static_cast<double>(range.min);
  for (int r = 0; r < H; ++r) {
    for (int c = 0; c < W; ++c) {
      const float v = values(r, c);
      Rgba px = o.nan_color;
      if (!std::isnan(v)) {
        double t = 0.5;
        if (span > 0.0) t = (static_cast<double>(v) - range.min) / span;  // +-inf clamp in colourAt
        if (std::isinf(v)) t = v > 0 ? 1.0 : 0.0;
        auto rgb = cmap.colourAt(t);
        if (o.hillshade) {
          const float s = shade(r, c);
          const double k = o.ambient + (1.0 - o.ambient) * (std::isfinite(s) ? s : 1.0);
          for (auto& ch : rgb) ch *= k;
        }
        px = Rgba{to8(rgb[0]), to8(rgb[1]), to8(rgb[2]), 255};
      }
      for (int dr = 0; dr < S; ++dr) {
        std::uint8_t* row = img.rgba.data() + (static_cast<std::size_t>(r * S + dr) * img.width + c * S) * 4;
        for (int dc = 0; dc < S; ++dc) {
          row[dc * 4 + 0] = px.r;
          row[dc * 4 + 1] = px.g;
          row[dc * 4 + 2] = px.b;
          row[dc * 4 + 3] = px.a;
        }
      }
    }
  }
  return img;
}

void writePng(const Image& image, const fs::path& path) {
  if (image.width <= 0 || image.height <= 0 ||
      image.rgba.size() != static_cast<std::size_t>(image.width) * static_cast<std::size_t>(image.height) * 4)
    throw OutputError("cannot write PNG '" + path.string() + "': image has inconsistent size " +
                      std::to_string(image.width) + "x" + std::to_string(image.height));
  detail::ensureGdalRegistered();
  replaceFileAtomically(path, [&](const fs::path& tmp) {
    detail::ScopedGdalOption no_pam("GDAL_PAM_ENABLED", "NO");
    detail::GdalErrorCapture errors;
    auto fail = [&](const std::string& what) {
      throw OutputError("cannot write PNG '" + path.string() + "': " + what +
                        (errors.failed() ? " (" + errors.message() + ")" : std::string()));
    };
    GDALDriver* mem_drv = GetGDALDriverManager()->GetDriverByName("MEM");
    GDALDriver* png_drv = GetGDALDriverManager()->GetDriverByName("PNG");
    if (!mem_drv || !png_drv) fail("GDAL lacks the MEM or PNG driver");
    struct Closer {
      void operator()(GDALDataset* ds) const { GDALClose(GDALDataset::ToHandle(ds)); }
    };
    std::unique_ptr<GDALDataset, Closer> mem(mem_drv->Create("", image.width, image.height, 4, GDT_Byte, nullptr));
    if (!mem) fail("cannot create the in-memory image");
    static const GDALColorInterp kInterp[4] = {GCI_RedBand, GCI_GreenBand, GCI_BlueBand, GCI_AlphaBand};
    for (int b = 0; b < 4; ++b) {
      GDALRasterBand* band = mem->GetRasterBand(b + 1);
      band->SetColorInterpretation(kInterp[b]);
      // Interleaved RGBA: pixel stride 4 bytes, line stride 4 * width, offset b.
      if (band->RasterIO(GF_Write, 0, 0, image.width, image.height, const_cast<std::uint8_t*>(image.rgba.data()) + b,
                         image.width, image.height, GDT_Byte, 4, static_cast<GSpacing>(image.width) * 4,
                         nullptr) != CE_None)
        fail("filling the in-memory image failed");
    }
    CPLStringList co;
    co.SetNameValue("ZLEVEL", "6");
    GDALDataset* out = png_drv->CreateCopy(tmp.c_str(), mem.get(), FALSE, co.List(), nullptr, nullptr);
    if (!out) fail("the PNG driver failed");
    GDALClose(GDALDataset::ToHandle(out));
    if (errors.failed()) fail("GDAL reported an error while writing");
  });
}

Image renderPicture(const LayeredMap& map, const std::string& layer, const RenderOptions& options,
                    const std::optional<Annotation>& annotation) {
  if (!annotation) return renderLayer(map, layer, options);
  // The colour bar needs the range the render used: resolve it once (an automatic range sorts
  // the whole layer). A degenerate automatic range stays automatic (a fixed one must have
  // min < max).
  RenderOptions o = options;
  const ValueRange r = renderRange(map, map.layerId(layer), o);
  if (r.min < r.max) o.range = r;
  Image img = renderLayer(map, layer, o);
  if (!annotation->outline_regions.empty())
    outlineRegions(img, map, annotation->outline_regions, o.scale, annotation->outline_colour);
  return annotate(img, map, layer, o, *annotation);
}

void renderPng(const LayeredMap& map, const std::string& layer, const fs::path& path, const RenderOptions& options,
               const std::optional<Annotation>& annotation) {
  writePng(renderPicture(map, layer, options, annotation), path);
}

void outlineRegions(Image& img, const LayeredMap& map, const std::string& regions, int scale, Rgba colour) {
  const RasterF z = northUpRaster(map, map.layerId(regions));  // rows = y (north first), cols = x
  const int H = static_cast<int>(z.rows()), W = static_cast<int>(z.cols()), S = scale;
  if (S < 1 || img.width != W * S || img.height != H * S)
    throw std::invalid_argument("outlineRegions: the image is not the map at the given scale");
  auto paint = [&](int px, int py) {
    std::uint8_t* p = img.rgba.data() + (static_cast<std::size_t>(py) * static_cast<std::size_t>(img.width) +
                                         static_cast<std::size_t>(px)) * 4;
    p[0] = colour.r;
    p[1] = colour.g;
    p[2] = colour.b;
    p[3] = colour.a;
  };
  auto differ = [&](int r0, int c0, int r1, int c1) {
    const float a = z(r0, c0), b = z(r1, c1);
    return std::isfinite(a) && std::isfinite(b) && a != b;
  };
  for (int r = 0; r < H; ++r)
    for (int c = 0; c < W; ++c) {
      if (c + 1 < W && differ(r, c, r, c + 1))  // vertical edge between columns c and c + 1
        for (int k = 0; k < S; ++k) {
          paint(c * S + S - 1, r * S + k);
          paint((c + 1) * S, r * S + k);
        }
      if (r + 1 < H && differ(r, c, r + 1, c))  // horizontal edge between rows r and r + 1
        for (int k = 0; k < S; ++k) {
          paint(c * S + k, r * S + S - 1);
          paint(c * S + k, (r + 1) * S);
        }
    }
}

}  // namespace terramap::io

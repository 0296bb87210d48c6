#pragma once
// Internal to terramap_io: the RGBA canvas, the FreeType text and the tick arithmetic that
// annotate.cpp (map pictures) and chart.cpp (plots) share. Not installed.
#include <terramap/core/error.hpp>
#include <terramap/io/render.hpp>

#include <ft2build.h>
#include FT_FREETYPE_H

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <memory>
#include <mutex>
#include <string>

namespace terramap::io::detail {

inline constexpr const char* kDefaultFont = "/usr/share/fonts/truetype/dejavu/DejaVuSans.ttf";
inline const Rgba kInk{30, 30, 30, 255};
inline const Rgba kWhite{255, 255, 255, 255};

// ---- canvas ----------------------------------------------------------------------------------

struct Canvas {
  Image img;
  Canvas(int w, int h) {
    img.width = w;
    img.height = h;
    img.rgba.assign(static_cast<std::size_t>(w) * static_cast<std::size_t>(h) * 4, 255);
  }
  void set(int x, int y, Rgba c) {
    if (x < 0 || y < 0 || x >= img.width || y >= img.height) return;
    std::uint8_t* p = img.rgba.data() + (static_cast<std::size_t>(y) * img.width + x) * 4;
    p[0] = c.r, p[1] = c.g, p[2] = c.b, p[3] = c.a;
  }
  /// Alpha-blends `c` with coverage a in [0, 255] over an opaque pixel.
  void blend(int x, int y, Rgba c, int a) {
    if (x < 0 || y < 0 || x >= img.width || y >= img.height || a <= 0) return;
    std::uint8_t* p = img.rgba.data() + (static_cast<std::size_t>(y) * img.width + x) * 4;
    p[0] = static_cast<std::uint8_t>((c.r * a + p[0] * (255 - a) + 127) / 255);
    p[1] = static_cast<std::uint8_t>((c.g * a + p[1] * (255 - a) + 127) / 255);
    p[2] = static_cast<std::uint8_t>((c.b * a + p[2] * (255 - a) + 127) / 255);
    p[3] = 255;
  }
  void fill(int x0, int y0, int w, int h, Rgba c) {
    for (int y = y0; y < y0 + h; ++y)
      for (int x = x0; x < x0 + w; ++x) set(x, y, c);
  }
  void frame(int x0, int y0, int w, int h, Rgba c) {
    fill(x0 - 1, y0 - 1, w + 2, 1, c);
    fill(x0 - 1, y0 + h, w + 2, 1, c);
    fill(x0 - 1, y0, 1, h, c);
    fill(x0 + w, y0, 1, h, c);
  }
  void paste(const Image& src, int x0, int y0) {
    for (int y = 0; y < src.height; ++y)
      for (int x = 0; x < src.width; ++x) {
        const std::uint8_t* s = src.rgba.data() + (static_cast<std::size_t>(y) * src.width + x) * 4;
        // Transparent (unknown) cells show the canvas: blend by the source's alpha.
        blend(x0 + x, y0 + y, Rgba{s[0], s[1], s[2], 255}, s[3]);
      }
  }
};

// ---- text ------------------------------------------------------------------------------------

/// One FreeType face, loaded once per process (FreeType objects are not thread-safe: guarded).
class Font {
 public:
  static Font& get() {
    static std::mutex mu;
    static std::unique_ptr<Font> font;
    std::lock_guard<std::mutex> lock(mu);
    const char* env = std::getenv("TERRAMAP_FONT");
    const std::string path = env && *env ? env : kDefaultFont;
    if (!font || font->path_ != path) font.reset(new Font(path));
    return *font;
  }
  ~Font() {
    if (face_) FT_Done_Face(face_);
    if (lib_) FT_Done_FreeType(lib_);
  }
  std::mutex& mutex() { return mu_; }

  /// Width in pixels of `text` at `px` pixels per em.
  int width(const std::string& text, int px) {
    FT_Set_Pixel_Sizes(face_, 0, static_cast<FT_UInt>(px));
    long w = 0;
    for (unsigned char ch : text)
      if (FT_Load_Char(face_, ch, FT_LOAD_DEFAULT) == 0) w += face_->glyph->advance.x >> 6;
    return static_cast<int>(w);
  }
  /// Draws `text` with its baseline at row y, starting at column x.
  void draw(Canvas& c, int x, int y, const std::string& text, int px, Rgba colour) {
    FT_Set_Pixel_Sizes(face_, 0, static_cast<FT_UInt>(px));
    for (unsigned char ch : text) {
      if (FT_Load_Char(face_, ch, FT_LOAD_RENDER) != 0) continue;
      const FT_GlyphSlot g = face_->glyph;
      const FT_Bitmap& b = g->bitmap;
      for (unsigned r = 0; r < b.rows; ++r)
        for (unsigned k = 0; k < b.width; ++k)
          c.blend(x + g->bitmap_left + static_cast<int>(k), y - g->bitmap_top + static_cast<int>(r), colour,
                  b.buffer[r * static_cast<unsigned>(b.pitch) + k]);
      x += static_cast<int>(g->advance.x >> 6);
    }
  }

 private:
  explicit Font(std::string path) : path_(std::move(path)) {
    if (FT_Init_FreeType(&lib_) != 0) throw OutputError("cannot initialise FreeType for picture labels");
    if (FT_New_Face(lib_, path_.c_str(), 0, &face_) != 0) {
      FT_Done_FreeType(lib_);
      lib_ = nullptr;
      throw OutputError("cannot load the font for picture labels: '" + path_ +
                        "' (install fonts-dejavu-core, or point TERRAMAP_FONT at a TrueType file)");
    }
  }
  std::string path_;
  FT_Library lib_ = nullptr;
  FT_Face face_ = nullptr;
  std::mutex mu_;
};

// ---- numbers ---------------------------------------------------------------------------------

/// A "nice" step (1, 2, 2.5 or 5 times a power of ten) giving about `n` intervals over `span`.
inline double niceStep(double span, int n) {
  const double raw = span / n, p = std::pow(10.0, std::floor(std::log10(raw))), f = raw / p;
  const double m = f <= 1.0 ? 1.0 : f <= 2.0 ? 2.0 : f <= 2.5 ? 2.5 : f <= 5.0 ? 5.0 : 10.0;
  return m * p;
}

/// v with as many decimals as the step needs (0.25 -> 2, 0.5 -> 1, 2 -> 0, 2.5 -> 1).
inline std::string label(double v, double step) {
  int decimals = 0;
  for (double s = step; decimals < 6 && std::abs(s - std::round(s)) > 1e-9 * std::max(1.0, s); s *= 10) ++decimals;
  char b[64];
  std::snprintf(b, sizeof b, "%.*f", decimals, std::abs(v) < step * 1e-6 ? 0.0 : v);
  return b;
}

/// The largest nice length (1, 2, 5 x 10^k m) not longer than `max_m`.
inline double niceLength(double max_m) {
  const double p = std::pow(10.0, std::floor(std::log10(max_m)));
  for (double m : {5.0, 2.0, 1.0})
    if (m * p <= max_m) return m * p;
  return p;
}

}  // namespace terramap::io::detail

// `terramap export`: a snapshot's layers as a GeoTIFF (for GIS) or PNG renders (for eyes).
#include "command.hpp"

#include <terramap/core/error.hpp>
#include <terramap/io/geotiff.hpp>
#include <terramap/io/output_budget.hpp>
#include <terramap/io/render.hpp>
#include <terramap/io/snapshot.hpp>

#include <cctype>
#include <filesystem>
#include <iostream>
#include <memory>
#include <optional>
#include <set>
#include <string>
#include <vector>

namespace terramap::cli {
namespace {

namespace fs = std::filesystem;

struct ExportOptions {
  std::string snapshot;
  std::vector<std::string> layers;
  std::string format;
  std::string out;
  // png
  std::string colormap = "viridis";
  bool hillshade = false;
  double azimuth_deg = 315.0, altitude_deg = 45.0, z_factor = 1.0, ambient = 0.0;
  std::vector<double> range;        // empty or {min, max}
  std::vector<double> percentiles;  // empty or {low, high}
  int scale = 1;
  std::string nan_color = "transparent";
  // geotiff
  int epsg = 0;
  std::vector<double> origin;  // empty or {easting, northing}
  bool no_compress = false;
  bool raw = false;
};

/// Layer names become file names: keep them readable but never let one escape the folder.
std::string safeFileStem(const std::string& name) {
  std::string s;
  for (const char ch : name) {
    const bool ok = (ch >= 'a' && ch <= 'z') || (ch >= 'A' && ch <= 'Z') || (ch >= '0' && ch <= '9') || ch == '_' ||
                    ch == '-' || ch == '.';
    s += ok ? ch : '_';
  }
  if (s.empty() || s == "." || s == "..") s = "layer";
  return s;
}

std::string inferFormat(const std::string& out) {
  std::string ext = fs::path(out).extension().string();
  for (auto& c : ext) c = static_cast<char>(std::tolower(static_cast<unsigned char>(c)));
  if (ext == ".tif" || ext == ".tiff") return "geotiff";
  if (ext == ".png") return "png";
  return "";
}

int usage(const std::string& msg) {
  std::cerr << "terramap export: " << msg << "\nRun 'terramap export --help' for the options.\n";
  return kUsage;
}

int runExport(const ExportOptions& o, const std::set<std::string>& given) {
  std::string format = o.format;
  if (format.empty()) format = inferFormat(o.out);
  if (format.empty()) return usage("--format is required (geotiff or png) unless --out ends in .tif/.tiff/.png");
  // Options that would be silently ignored are refused, so a typo'd intent is noticed.
  static const std::vector<std::string> kPngOnly = {"--colormap", "--hillshade",   "--azimuth", "--altitude",
                                                     "--z-factor", "--ambient",     "--range",   "--percentiles",
                                                     "--scale",    "--nan-color"};
  static const std::vector<std::string> kTiffOnly = {"--epsg", "--origin", "--no-compress"};
  for (const std::string& opt : format == "png" ? kTiffOnly : kPngOnly)
    if (given.count(opt))
      return usage(opt + " does not apply to --format " + format);
  {
    std::set<std::string> seen;
    for (const auto& l : o.layers)
      if (!seen.insert(l).second) return usage("layer '" + l + "' is given twice");
  }

  const LayeredMap map = io::loadSnapshot(o.snapshot);  // InputError -> exit 4
  for (const auto& l : o.layers) map.layerId(l);         // LayerError -> exit 6, before writing anything
  // A sparse snapshot of a few bytes can declare any size; its raster is whole (exit 4).
  io::requireRasterOutputBudget(map.geometry(), format, o.scale, o.snapshot, true);
  const fs::path snap(o.snapshot);
  const fs::path stem = snap.parent_path() / snap.stem();

  if (format == "geotiff") {
    io::GeoTiffOptions g;
    g.georef.epsg = o.epsg;
    if (o.origin.size() == 2) {
      g.georef.origin_easting = o.origin[0];
      g.georef.origin_northing = o.origin[1];
    }
    g.compress = !o.no_compress;
    const fs::path out = o.out.empty() ? fs::path(stem.string() + ".tif") : fs::path(o.out);
    io::writeGeoTiff(map, o.layers, out, g);
    std::cout << "wrote " << out.string() << " (GeoTIFF, " << o.layers.size() << " band"
              << (o.layers.size() > 1 ? "s" : "") << ", " << map.geometry().size().x() << "x"
              << map.geometry().size().y() << " px, "
              << (o.epsg ? "EPSG:" + std::to_string(o.epsg) : std::string("local metric CRS")) << ")\n";
    return kOk;
  }

  io::RenderOptions r;
  r.colormap = o.colormap;
  io::Colormap::byName(r.colormap);  // ConfigError (exit 3) with did-you-mean before any work
  if (o.range.size() == 2) r.range = io::ValueRange{static_cast<float>(o.range[0]), static_cast<float>(o.range[1])};
  if (o.percentiles.size() == 2) {
    r.low_percentile = o.percentiles[0];
    r.high_percentile = o.percentiles[1];
  }
  r.hillshade = o.hillshade;
  r.azimuth_deg = o.azimuth_deg;
  r.altitude_deg = o.altitude_deg;
  r.z_factor = o.z_factor;
  r.ambient = o.ambient;
  r.scale = o.scale;
  if (o.nan_color == "grey") r.nan_color = io::Rgba{128, 128, 128, 255};

  std::vector<std::pair<std::string, fs::path>> jobs;
  if (o.layers.size() == 1) {
    jobs.emplace_back(o.layers[0], o.out.empty() ? fs::path(stem.string() + "_" + safeFileStem(o.layers[0]) + ".png")
                                                 : fs::path(o.out));
  } else {
    if (!o.out.empty() && inferFormat(o.out) == "png")
      return usage("--out '" + o.out + "' looks like a file, but " + std::to_string(o.layers.size()) +
                   " PNG layers need a folder (one <layer>.png each)");
    if (!o.out.empty()) {
      std::error_code ec;
      fs::create_directories(o.out, ec);
      if (ec) throw OutputError("cannot create output folder '" + o.out + "': " + ec.message());
    }
    for (const auto& l : o.layers)
      jobs.emplace_back(l, o.out.empty() ? fs::path(stem.string() + "_" + safeFileStem(l) + ".png")
                                         : fs::path(o.out) / (safeFileStem(l) + ".png"));
  }
  for (const auto& [layer, path] : jobs) {
    const io::Image img =
        io::renderPicture(map, layer, r, o.raw ? std::nullopt : std::optional<io::Annotation>(io::Annotation{}));
    io::writePng(img, path);
    std::cout << "wrote " << path.string() << " (PNG " << img.width << "x" << img.height << ", layer '" << layer
              << "', " << io::Colormap::byName(r.colormap).name() << (r.hillshade ? ", hillshaded" : "") << ")\n";
  }
  return kOk;
}

void setupExport(CLI::App& app, std::function<int()>& run) {
  auto o = std::make_shared<ExportOptions>();
  CLI::App* sub = app.add_subcommand(
      "export",
      "Export layers of a map snapshot (.tmap) as a GeoTIFF (one Float32 band per layer, NaN =\n"
      "unknown = nodata) or as coloured PNG images (one per layer).");
  sub->footer(
      "Orientation: both formats are north-up. Map x is easting and map y is northing; image row 0\n"
      "is the largest map y, column 0 the smallest map x (a transposition of the map's (i, j)\n"
      "index order, see include/terramap/io/geotiff.hpp).\n"
      "CRS (GeoTIFF): a local engineering CRS in metres unless --epsg gives a projected CRS in\n"
      "metres; --origin E N is the easting/northing of map position (0, 0).\n"
      "PNG colours: value range from --range, else the 2nd-98th percentile of the finite values\n"
      "(--percentiles), symmetric about 0 for the diverging maps rdbu/rdbu_r; unknown cells are\n"
      "transparent (or --nan-color grey). --hillshade multiplies the colours with a Horn hillshade\n"
      "of the same layer, read as elevation in metres.\n"
      "Output names: --out is the file for GeoTIFF and for a single PNG layer, a folder (created\n"
      "if needed) holding <layer>.png for several PNG layers. Default: next to the snapshot,\n"
      "<snapshot>.tif or <snapshot>_<layer>.png. Files are written atomically (temp + rename).\n"
      "Exit codes: 0 ok, 2 usage, 3 bad option value (colormap, range, EPSG), 4 unreadable or\n"
      "corrupt snapshot, 6 unknown layer, 7 cannot write the output.\n"
      "Examples:\n"
      "  terramap export out/demo/map.tmap --layer elevation --layer variance --format geotiff\n"
      "  terramap export map.tmap --layer elevation --format geotiff --epsg 32632 --origin 500000 5200000\n"
      "  terramap export map.tmap --layer elevation --format png --hillshade --scale 4 --out elev.png\n"
      "  terramap export map.tmap --layer error --format png --colormap rdbu --range -0.1 0.1");
  sub->add_option("snapshot", o->snapshot, "map snapshot file (.tmap) written by terramap")->required();
  sub->add_option("--layer,-l", o->layers, "layer to export; repeat for several (order = band order)")
      ->required()
      ->expected(1)
      ->multi_option_policy(CLI::MultiOptionPolicy::TakeAll);
  sub->add_option("--format,-f", o->format, "geotiff or png (inferred from --out's extension if omitted)")
      ->check(CLI::IsMember({"geotiff", "png"}));
  sub->add_option("--out,-o", o->out, "output file (or folder for several PNG layers)");
  sub->add_option("--colormap", o->colormap,
                  "png: " + [] {
                    std::string s;
                    for (const auto& n : io::Colormap::names()) s += (s.empty() ? "" : ", ") + n;
                    return s;
                  }())
      ->capture_default_str();
  sub->add_flag("--hillshade", o->hillshade, "png: shade the layer as elevation (Horn's method)");
  sub->add_option("--azimuth", o->azimuth_deg, "png: light azimuth [deg] clockwise from north")->capture_default_str();
  sub->add_option("--altitude", o->altitude_deg, "png: light altitude [deg] above the horizon, (0, 90]")
      ->capture_default_str();
  sub->add_option("--z-factor", o->z_factor, "png: vertical exaggeration for the hillshade, > 0")
      ->capture_default_str();
  sub->add_option("--ambient", o->ambient, "png: hillshade floor in [0, 1) (0 = pure multiply)")
      ->capture_default_str();
  sub->add_option("--range", o->range, "png: fixed value range MIN MAX (layer units)")->expected(2);
  sub->add_option("--percentiles", o->percentiles, "png: automatic range percentiles LOW HIGH (default 2 98)")
      ->expected(2);
  sub->add_option("--scale", o->scale, "png: pixels per cell edge, 1..64")->capture_default_str();
  sub->add_flag("--raw", o->raw,
                "png: the layer's pixels only (overlays the GeoTIFF); default: with title, colour bar in "
                "the layer's unit, scale bar and axes");
  sub->add_option("--nan-color", o->nan_color, "png: colour of unknown cells: transparent or grey")
      ->check(CLI::IsMember({"transparent", "grey"}))
      ->capture_default_str();
  CLI::Option* origin =
      sub->add_option("--origin", o->origin, "geotiff: easting and northing [m] of map position (0, 0)")->expected(2);
  sub->add_option("--epsg", o->epsg, "geotiff: EPSG code of a projected CRS in metres (e.g. 32632 = UTM 32N)")
      ->needs(origin);
  sub->add_flag("--no-compress", o->no_compress, "geotiff: write uncompressed (default: DEFLATE, lossless)");
  sub->callback([&run, o, sub] {
    std::set<std::string> given;
    for (const CLI::Option* opt : sub->get_options())
      if (opt->count() > 0) given.insert(opt->get_name());
    run = [o, given] { return runExport(*o, given); };
  });
}

const Registrar kRegisterExport{Command{"export", setupExport}};

}  // namespace
}  // namespace terramap::cli

// libFuzzer target: GeoTIFF DEMs through terramap::sim::loadDem (terramap::io::readRaster's
// budget check before GDAL decodes, the geotransform and band checks, hole filling).
// Only GDAL's GTiff driver is left registered: the DEM loader is for GeoTIFFs, and the other
// ~200 drivers are GDAL's own code to fuzz (OSS-Fuzz does), not terramap's.
#include "fuzz_support.hpp"

#include <terramap/io/geotiff.hpp>
#include <terramap/sim/dem.hpp>

#include <cpl_conv.h>
#include <cpl_error.h>
#include <gdal.h>

#include <cstring>

extern "C" int LLVMFuzzerInitialize(int*, char***) {
  using namespace terramap;
  fuzz::setUp();
  CPLSetErrorHandler(CPLQuietErrorHandler);
  // GDAL's block cache defaults to 5 % of RAM; it would be mistaken for a leak by -rss_limit_mb.
  CPLSetConfigOption("GDAL_CACHEMAX", "32");
  // readRaster registers the drivers once (std::call_once): let it do so now, then drop all
  // but GTiff, so a later call does not register them again.
  try {
    io::readRaster("/nonexistent/terramap-fuzz.tif");
  } catch (const InputError&) {
  }
  for (int i = GDALGetDriverCount() - 1; i >= 0; --i) {
    GDALDriverH d = GDALGetDriver(i);
    if (std::strcmp(GDALGetDriverShortName(d), "GTiff") != 0) {
      GDALDeregisterDriver(d);
      GDALDestroyDriver(d);
    }
  }
  return 0;
}

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size) {
  static terramap::fuzz::ScratchFile file("geotiff", ".tif");
  const std::string& path = file.write(data, size);
  using namespace terramap;
  fuzz::expectInputErrorsOnly([&] {
    const fuzz::BudgetScope budget(fuzz::kDemBudgetBytes);
    sim::DemSpec spec;
    spec.path = path;
    spec.format = sim::DemFormat::GeoTiff;
    spec.fill_holes = true;
    const sim::DemGrid g = sim::loadDem(spec);
    if (g.z.size() != static_cast<std::size_t>(g.nx) * static_cast<std::size_t>(g.ny)) __builtin_trap();
  });
  return 0;
}

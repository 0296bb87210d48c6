// libFuzzer target: ESRI ASCII DEMs through terramap::sim::loadDem (readEsriAscii, the origin
// shift and hole filling), then a bilinear lookup in the grid that loaded.
#include "fuzz_support.hpp"

#include <terramap/sim/dem.hpp>

extern "C" int LLVMFuzzerInitialize(int*, char***) {
  terramap::fuzz::setUp();
  return 0;
}

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size) {
  static terramap::fuzz::ScratchFile file("dem", ".asc");
  const std::string& path = file.write(data, size);
  using namespace terramap;
  fuzz::expectInputErrorsOnly([&] {
    const fuzz::BudgetScope budget(fuzz::kDemBudgetBytes);
    sim::DemSpec spec;
    spec.path = path;
    spec.format = sim::DemFormat::EsriAscii;
    spec.fill_holes = true;
    const sim::DemGrid g = sim::loadDem(spec);
    if (g.z.size() != static_cast<std::size_t>(g.nx) * static_cast<std::size_t>(g.ny)) __builtin_trap();
    g.heightAt(g.x0_m + 0.5 * g.cell_m, g.y0_m + 0.5 * g.cell_m);
  });
  return 0;
}

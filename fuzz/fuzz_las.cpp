// libFuzzer target: terramap::io::readLasHeader / readLas, and the LAS DEM loader (ground
// points gridded by terramap::sim::loadDem), which trusts the coordinates readLas returns.
#include "fuzz_support.hpp"

#include <terramap/io/readers.hpp>
#include <terramap/sim/dem.hpp>

extern "C" int LLVMFuzzerInitialize(int*, char***) {
  terramap::fuzz::setUp();
  return 0;
}

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size) {
  static terramap::fuzz::ScratchFile file("las", ".las");
  const std::string& path = file.write(data, size);
  using namespace terramap;
  fuzz::expectInputErrorsOnly([&] {
    const io::LasHeader header = io::readLasHeader(path);
    io::LasReadOptions options;
    options.keep_double_positions = true;
    const io::LasCloud cloud = io::readLas(path, options);
    if (cloud.size() != header.point_count) __builtin_trap();
  });
  fuzz::expectInputErrorsOnly([&] {
    const fuzz::BudgetScope budget(fuzz::kDemBudgetBytes);
    sim::DemSpec spec;
    spec.path = path;
    spec.format = sim::DemFormat::Las;
    sim::loadDem(spec);
  });
  return 0;
}

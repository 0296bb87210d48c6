// libFuzzer target: simulator scenarios through terramap::sim::parseScenario (the strict
// YAML reader, every section's keys and ranges, the terrain's size against the budget).
// Relative DEM paths resolve against a folder that does not exist, so a DEM is refused as an
// input error; the DEM readers have targets of their own.
#include "fuzz_support.hpp"

#include <terramap/sim/scenario.hpp>

extern "C" int LLVMFuzzerInitialize(int*, char***) {
  terramap::fuzz::setUp();
  return 0;
}

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size) {
  const std::string text(reinterpret_cast<const char*>(data), size);
  terramap::fuzz::expectInputErrorsOnly([&] {
    terramap::sim::parseScenario(text, "fuzz.yaml", "/nonexistent/terramap-fuzz");
  });
  return 0;
}

// The library's one export: the plugin record and factory (abi.hpp). Kept apart from
// the plugin's other sources so that blade_sweep_kernels (tests, benchmarks) holds the classes
// without the C symbols.
#include <terramap/plugin/abi.hpp>

#include "blade_sweep.hpp"

TERRAMAP_PLUGIN(terramap::plugins::BladeSweep, "blade_sweep", "1.0.0",
                "blind mapping: blade swept volume cuts and deposits soil, extracts FEE geometry per sweep")

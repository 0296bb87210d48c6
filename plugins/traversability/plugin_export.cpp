// The library's one export: the plugin record and factory (abi.hpp). Kept apart from
// traversability.cpp so that traversability_kernels (tests, benchmarks) holds the class without the C symbols.
#include <terramap/plugin/abi.hpp>

#include "traversability.hpp"

TERRAMAP_PLUGIN(terramap::plugins::Traversability, "traversability", "1.0.0",
                "slope, roughness and step height of an elevation layer, and a traversability in [0, 1]")

// The library's one export: the plugin record and factory (abi.hpp), apart from the classes so
// that octomap_strata_kernels (tests, benchmarks) holds them without the C symbols.
#include <terramap/plugin/abi.hpp>

#include "octomap_strata.hpp"

TERRAMAP_PLUGIN(terramap::plugins::OctomapStrata, "octomap_strata", "1.0.0",
                "Subsurface soil memory: soil_pinn's estimates by depth in an OctoMap tree, the soil expected in the next cut")

// The library's one export: the plugin record and factory (abi.hpp). Kept apart from
// the plugin's other sources so that soil_erosion_kernels (tests, benchmarks) holds the classes
// without the C symbols.
#include <terramap/plugin/abi.hpp>

#include "soil_erosion.hpp"

TERRAMAP_PLUGIN(terramap::plugins::SoilErosion, "soil_erosion", "1.0.0",
                "Mohr-Coulomb slip of loose soil around the blade after each sweep (4-colour parallel)")

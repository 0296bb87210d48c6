// The one TERRAMAP_PLUGIN of the soil_erosion library.
#include <terramap/plugin/abi.hpp>

#include "soil_erosion.hpp"

// Gives the info record external linkage (a namespace-scope const alone has internal linkage,
// so abi.hpp's macro by itself would not export it).
extern "C" __attribute__((visibility("default"))) const terramap_plugin_info_t terramap_plugin_info;

TERRAMAP_PLUGIN(terramap::blind::SoilErosion, "soil_erosion", "1.0.0",
                "Mohr-Coulomb slip of loose soil around the blade after each sweep (4-colour parallel)")

// The library's one export: the plugin record and factory (abi.hpp). Kept apart from
// soil_fit.cpp so that soil_fit_kernels (tests) holds the class without the C symbols.
#include <terramap/plugin/abi.hpp>

#include "soil_fit.hpp"

TERRAMAP_PLUGIN(terramap::plugins::SoilFit, "soil_fit", "1.0.0",
                "the soil fitted jointly to the force of the machine's last sweeps (pooled FEE fit)")

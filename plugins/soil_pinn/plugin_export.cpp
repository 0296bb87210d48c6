// The library's one export: the plugin record and factory (abi.hpp). Kept apart from the
// plugin's other sources so that soil_pinn_kernels (tests, benchmarks) holds the classes
// without the C symbols.
#include <terramap/plugin/abi.hpp>

#include "soil_pinn_plugin.hpp"

TERRAMAP_PLUGIN(terramap::plugins::SoilPinn, "soil_pinn", "0.1.0",
                "PINN soil estimator: per-sweep soil parameters with variances from the observation history and the FEE geometry")

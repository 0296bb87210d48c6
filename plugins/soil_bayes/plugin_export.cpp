// The library's one export: the plugin record and factory (abi.hpp), apart from the classes so
// that soil_bayes_kernels (tests) holds them without the C symbols.
#include <terramap/plugin/abi.hpp>

#include "soil_bayes.hpp"

TERRAMAP_PLUGIN(terramap::plugins::SoilBayes, "soil_bayes", "1.0.0",
                "Bayesian soil-property layers: soil_pinn's per-sweep estimates fused over the wedge ahead of the blade")

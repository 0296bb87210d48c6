// The library's one export: the plugin record and factory (abi.hpp). Kept apart from
// soil_oracle.cpp so that soil_oracle_kernels (tests) holds the class without the C symbols.
#include <terramap/plugin/abi.hpp>

#include "soil_oracle.hpp"

TERRAMAP_PLUGIN(terramap::plugins::SoilOracle, "soil_oracle", "1.0.0",
                "evaluation only: publishes a table of truth soil as the estimate of every sweep")

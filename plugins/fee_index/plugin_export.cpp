// The library's one export: the plugin record and factory (abi.hpp), apart from the classes so
// that fee_index_kernels (tests) holds them without the C symbols.
#include <terramap/plugin/abi.hpp>

#include "fee_index.hpp"

TERRAMAP_PLUGIN(terramap::plugins::FeeIndex, "fee_index", "1.0.0",
                "FEE index: the force of a reference cut on the fused soil layers, with its variance")

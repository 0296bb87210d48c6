// The library's one export: the plugin record and factory (abi.hpp). Kept apart from
// inpaint.cpp so that inpaint_kernels (tests, benchmarks) holds the class without the C symbols.
#include <terramap/plugin/abi.hpp>

#include "inpaint.hpp"

TERRAMAP_PLUGIN(terramap::plugins::Inpaint, "inpaint", "1.0.0",
                "Fills unknown cells by push-pull interpolation, up to a distance from data")

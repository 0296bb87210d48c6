// The library's one export: the plugin record and factory (abi.hpp). Kept apart from
// smooth_filter.cpp so that smooth_filter_kernels (tests, benchmarks) holds the class without the C symbols.
#include <terramap/plugin/abi.hpp>

#include "smooth_filter.hpp"

TERRAMAP_PLUGIN(terramap::plugins::SmoothFilter, "smooth_filter", "1.0.0",
                "NaN-aware separable Gaussian smoothing of a layer")

// The one TERRAMAP_PLUGIN of the blade_sweep library.
#include <terramap/plugin/abi.hpp>

#include "blade_sweep.hpp"

// A namespace-scope const object has internal linkage in C++ even inside extern "C" { }, so
// without this prior extern declaration the info record would not be exported (abi.hpp's
// macro alone produced a library without `terramap_plugin_info`; reported upstream).
extern "C" __attribute__((visibility("default"))) const terramap_plugin_info_t terramap_plugin_info;

TERRAMAP_PLUGIN(terramap::blind::BladeSweep, "blade_sweep", "1.0.0",
                "blind mapping: blade swept volume cuts and deposits soil, extracts FEE geometry per sweep")

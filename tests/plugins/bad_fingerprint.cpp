// Broken on purpose: built "with another compiler".
#include <terramap/plugin/abi.hpp>
extern "C" {
const terramap_plugin_info_t terramap_plugin_info = {
    TERRAMAP_PLUGIN_ABI_VERSION, static_cast<std::uint32_t>(sizeof(terramap_plugin_info_t)),
    "terramap-0.1;othercc-1;cxx11abi-0;eigen-3.0.0", "bad_fingerprint", "0.0.1", "wrong fingerprint"};
}

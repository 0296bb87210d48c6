// Broken on purpose: a valid info record but no create/destroy functions.
#include <terramap/plugin/abi.hpp>
extern "C" {
const terramap_plugin_info_t terramap_plugin_info = {
    TERRAMAP_PLUGIN_ABI_VERSION, static_cast<std::uint32_t>(sizeof(terramap_plugin_info_t)),
    TERRAMAP_BUILD_FINGERPRINT, "bad_missing_symbol", "0.0.1", "no create symbol"};
}

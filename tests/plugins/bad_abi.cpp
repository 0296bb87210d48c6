// Broken on purpose: claims ABI version 99.
#include <terramap/plugin/abi.hpp>
extern "C" {
const terramap_plugin_info_t terramap_plugin_info = {
    99u, static_cast<std::uint32_t>(sizeof(terramap_plugin_info_t)), TERRAMAP_BUILD_FINGERPRINT,
    "bad_abi", "0.0.1", "wrong ABI number"};
}

// Broken on purpose: the record size does not match the host's.
#include <terramap/plugin/abi.hpp>
extern "C" {
const terramap_plugin_info_t terramap_plugin_info = {
    TERRAMAP_PLUGIN_ABI_VERSION, static_cast<std::uint32_t>(sizeof(terramap_plugin_info_t) + 8),
    TERRAMAP_BUILD_FINGERPRINT, "bad_size", "0.0.1", "wrong record size"};
}

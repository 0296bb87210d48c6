// Broken on purpose: the record size does not match the host's.
#include <terramap/plugin/abi.hpp>
extern "C" {
const terramap_plugin_info_t terramap_plugin_info = {
    TERRAMAP_PLUGIN_ABI_VERSION, static_cast<std::uint32_t>(sizeof(terramap_plugin_info_t) + 8),
    TERRAMAP_BUILD_FINGERPRINT, "bad_size", "0.0.1", "wrong record size"};
}
// Exported like a real plugin's, so the refusal is about the record, not about a missing
// function (which is refused before loading).
extern "C" __attribute__((visibility("default"))) terramap::Plugin* terramap_plugin_create() { return nullptr; }
extern "C" __attribute__((visibility("default"))) void terramap_plugin_destroy(terramap::Plugin*) {}

// Broken on purpose: claims ABI version 99.
#include <terramap/plugin/abi.hpp>
extern "C" {
const terramap_plugin_info_t terramap_plugin_info = {
    99u, static_cast<std::uint32_t>(sizeof(terramap_plugin_info_t)), TERRAMAP_BUILD_FINGERPRINT,
    "bad_abi", "0.0.1", "wrong ABI number"};
}
// Exported like a real plugin's, so the refusal is about the record, not about a missing
// function (which is refused before loading).
extern "C" __attribute__((visibility("default"))) terramap::Plugin* terramap_plugin_create() { return nullptr; }
extern "C" __attribute__((visibility("default"))) void terramap_plugin_destroy(terramap::Plugin*) {}

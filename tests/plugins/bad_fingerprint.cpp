// Broken on purpose: built "with another compiler".
#include <terramap/plugin/abi.hpp>
extern "C" {
const terramap_plugin_info_t terramap_plugin_info = {
    TERRAMAP_PLUGIN_ABI_VERSION, static_cast<std::uint32_t>(sizeof(terramap_plugin_info_t)),
    "terramap-0.1;othercc-1;cxx11abi-0;eigen-3.0.0", "bad_fingerprint", "0.0.1", "wrong fingerprint"};
}
// Exported like a real plugin's, so the refusal is about the record, not about a missing
// function (which is refused before loading).
extern "C" __attribute__((visibility("default"))) terramap::Plugin* terramap_plugin_create() { return nullptr; }
extern "C" __attribute__((visibility("default"))) void terramap_plugin_destroy(terramap::Plugin*) {}

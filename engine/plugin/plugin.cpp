#include <terramap/plugin/plugin.hpp>

namespace terramap {

Plugin::~Plugin() = default;

const char* layerAccessName(LayerAccess a) {
  switch (a) {
    case LayerAccess::Read: return "read";
    case LayerAccess::Write: return "write";
    case LayerAccess::Create: return "create";
  }
  return "?";
}

const Record* RecordBus::latest(const std::string& type) const {
  auto it = latest_.find(type);
  return it == latest_.end() ? nullptr : &it->second;
}

void RecordBus::publishErased(const std::string& type, double stamp, std::shared_ptr<const void> p) {
  Record& r = latest_[type];
  r.type = type;
  r.sequence += 1;
  r.stamp = stamp;
  r.payload = std::move(p);
}

}  // namespace terramap

#include <terramap/plugin/plugin.hpp>

#include <algorithm>

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
  auto it = history_.find(type);
  return it == history_.end() || it->second.empty() ? nullptr : &it->second.back();
}

RecordBus::Since RecordBus::since(const std::string& type, long after) const {
  Since out;
  auto it = history_.find(type);
  if (it == history_.end() || it->second.empty()) return out;
  const std::deque<Record>& h = it->second;
  // Sequences are consecutive, so the ones after `after` that are gone are those below the
  // oldest kept.
  out.missed = std::max(0L, h.front().sequence - after - 1);
  for (const Record& r : h)
    if (r.sequence > after) out.records.push_back(r);
  return out;
}

void RecordBus::publishErased(const std::string& type, double stamp, std::shared_ptr<const void> p) {
  std::deque<Record>& h = history_[type];
  Record r;
  r.type = type;
  r.sequence = h.empty() ? 1 : h.back().sequence + 1;
  r.stamp = stamp;
  r.payload = std::move(p);
  h.push_back(std::move(r));
  while (h.size() > kHistory) h.pop_front();
}

}  // namespace terramap

namespace terramap {

void ChangeTracker::track(LayerId id) {
  if (tracks(id)) return;
  Layer l;
  l.id = id;
  layers_.push_back(std::move(l));
  marked_ = false;  // a new layer has no remembered state: report everything once
}

bool ChangeTracker::tracks(LayerId id) const {
  for (const auto& l : layers_)
    if (l.id == id) return true;
  return false;
}

std::vector<int> ChangeTracker::changed(const LayeredMap& map, LayerId id) const {
  std::vector<int> out;
  const Layer* layer = nullptr;
  for (const auto& l : layers_)
    if (l.id == id) layer = &l;
  const bool all = !marked_ || !layer || (map.startIndex() != start_).any() ||
                   map.geometry().center() != center_ ||
                   static_cast<int>(layer->writes.size()) != map.tileCount();
  for (int t = 0; t < map.tileCount(); ++t)
    if (all || map.tileWrites(id, t) != layer->writes[static_cast<size_t>(t)]) out.push_back(t);
  return out;
}

void ChangeTracker::mark(const LayeredMap& map) {
  for (auto& l : layers_) {
    l.writes.resize(static_cast<size_t>(map.tileCount()));
    for (int t = 0; t < map.tileCount(); ++t) l.writes[static_cast<size_t>(t)] = map.tileWrites(l.id, t);
  }
  start_ = map.startIndex();
  center_ = map.geometry().center();
  marked_ = true;
}

}  // namespace terramap

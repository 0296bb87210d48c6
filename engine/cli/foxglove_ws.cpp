#include "foxglove_ws.hpp"

#include <terramap/core/text.hpp>

#include <cpl_conv.h>
#include <cpl_string.h>
#include <nlohmann/json.hpp>

#include <cmath>
#include <cstddef>
#include <cstring>
#include <limits>
#include <memory>

namespace terramap::cli::foxglove {

using json = nlohmann::json;

namespace {

/// What a client sent, as an error message may quote it.
std::string clip(const std::string& s) { return s.size() <= 64 ? s : s.substr(0, 64) + "..."; }

/// GDAL's encoder (already linked for GeoTIFF) rather than one of our own.
std::string base64(const void* bytes, std::size_t n) {
  if (n > static_cast<std::size_t>(std::numeric_limits<int>::max() / 4 * 3))
    throw OutputError("a Foxglove message of " + std::to_string(n) + " bytes is too large to encode");
  std::unique_ptr<char, void (*)(void*)> s(
      CPLBase64Encode(static_cast<int>(n), static_cast<const GByte*>(bytes)), [](void* p) { CPLFree(p); });
  return s ? std::string(s.get()) : std::string();
}

json timeOf(double stamp_s) {
  const std::uint64_t ns = stampNs(stamp_s);
  return {{"sec", ns / 1000000000u}, {"nsec", ns % 1000000000u}};
}

json poseOf(const Eigen::Vector3d& t, const Eigen::Quaterniond& q) {
  return {{"position", {{"x", t.x()}, {"y", t.y()}, {"z", t.z()}}},
          {"orientation", {{"x", q.x()}, {"y", q.y()}, {"z", q.z()}, {"w", q.w()}}}};
}

json float32Field(const std::string& name, int offset) {
  return {{"name", name}, {"offset", offset}, {"type", 7}};  // 7 = FLOAT32 in foxglove.NumericType
}

/// `head` with "data": `b64` appended. Base64 needs no JSON escaping, so the megabytes of it are
/// appended as they are instead of going through the JSON writer's escaping.
std::string withData(const json& head, const std::string& b64) {
  std::string out = head.dump();
  out.pop_back();  // the closing brace
  out.reserve(out.size() + b64.size() + 12);
  out += ",\"data\":\"";
  out += b64;
  out += "\"}";
  return out;
}

// ---- the schemas' building blocks ----
json typed(const char* t) { return {{"type", t}}; }
json uinteger() { return {{"type", "integer"}, {"minimum", 0}}; }
json object(const std::vector<std::pair<const char*, json>>& props, const std::vector<std::string>& required) {
  json p = json::object();
  for (const auto& [k, v] : props) p[k] = v;
  return {{"type", "object"}, {"properties", p}, {"required", required}};
}
json timeSchema() {
  json nsec = uinteger();
  nsec["maximum"] = 999999999;
  return object({{"sec", uinteger()}, {"nsec", nsec}}, {"sec", "nsec"});
}
json poseSchema() {
  const json n = typed("number");
  return object({{"position", object({{"x", n}, {"y", n}, {"z", n}}, {"x", "y", "z"})},
                 {"orientation", object({{"x", n}, {"y", n}, {"z", n}, {"w", n}}, {"x", "y", "z", "w"})}},
                {"position", "orientation"});
}
json fieldsSchema() {
  json type = {{"type", "integer"}, {"minimum", 0}, {"maximum", 8}};
  return {{"type", "array"},
          {"items", object({{"name", typed("string")}, {"offset", uinteger()}, {"type", type}}, {"name", "offset", "type"})}};
}
json bytesSchema() { return {{"type", "string"}, {"contentEncoding", "base64"}}; }

/// An unsigned 32-bit id from a request, or an error naming the key.
bool uint32Of(const json& j, const char* key, std::uint32_t& out, std::string& error, const std::string& where) {
  const auto it = j.find(key);
  if (it == j.end() || !it->is_number_integer() || *it < 0 || *it > std::numeric_limits<std::uint32_t>::max()) {
    error = where + ": \"" + key + "\" must be an integer in [0, 4294967295]";
    return false;
  }
  out = it->get<std::uint32_t>();
  return true;
}

}  // namespace

bool offersSubprotocol(const std::string& header_value) {
  std::size_t start = 0;
  while (start <= header_value.size()) {
    std::size_t end = header_value.find(',', start);
    if (end == std::string::npos) end = header_value.size();
    std::string token = header_value.substr(start, end - start);
    const auto b = token.find_first_not_of(" \t"), e = token.find_last_not_of(" \t");
    token = b == std::string::npos ? "" : token.substr(b, e - b + 1);
    if (token == kSubprotocol) return true;
    start = end + 1;
  }
  return false;
}

std::string serverInfo(const std::string& session_id) {
  return json{{"op", "serverInfo"},
              {"name", "terramap"},
              {"capabilities", json::array()},
              {"supportedEncodings", json::array()},
              {"metadata", json::object()},
              {"sessionId", session_id}}
      .dump();
}

std::string advertise(const std::vector<Channel>& channels) {
  json list = json::array();
  for (const Channel& c : channels)
    list.push_back({{"id", c.id},
                    {"topic", c.topic},
                    {"encoding", "json"},
                    {"schemaName", c.schema_name},
                    {"schema", c.schema},
                    {"schemaEncoding", "jsonschema"}});
  return json{{"op", "advertise"}, {"channels", list}}.dump();
}

std::string status(Level level, const std::string& message, const std::string& id) {
  json j = {{"op", "status"}, {"level", static_cast<int>(level)}, {"message", message}};
  if (!id.empty()) j["id"] = id;
  return j.dump();
}

std::array<char, 13> messageDataHead(std::uint32_t subscription_id, std::uint64_t timestamp_ns) {
  std::array<char, 13> h{};
  h[0] = 0x01;
  for (int k = 0; k < 4; ++k) h[1 + k] = static_cast<char>((subscription_id >> (8 * k)) & 0xffu);
  for (int k = 0; k < 8; ++k) h[5 + k] = static_cast<char>((timestamp_ns >> (8 * k)) & 0xffu);
  return h;
}

std::variant<Subscribe, Unsubscribe, ClientError> parseClientMessage(const std::string& text) {
  const json j = json::parse(text, nullptr, false);
  if (j.is_discarded()) return ClientError{"not JSON: a request is {\"op\": \"subscribe\" | \"unsubscribe\", ...}"};
  if (!j.is_object()) return ClientError{"a request is a JSON object, {\"op\": ...}"};
  const auto op_it = j.find("op");
  if (op_it == j.end() || !op_it->is_string()) return ClientError{"\"op\" must be a string (subscribe, unsubscribe)"};
  const std::string op = op_it->get<std::string>();
  if (op == "subscribe") {
    const auto subs = j.find("subscriptions");
    if (subs == j.end() || !subs->is_array()) return ClientError{"subscribe: \"subscriptions\" must be an array"};
    Subscribe s;
    for (std::size_t k = 0; k < subs->size(); ++k) {
      const json& item = (*subs)[k];
      const std::string where = "subscribe: subscriptions[" + std::to_string(k) + "]";
      if (!item.is_object()) return ClientError{where + " must be an object {\"id\", \"channelId\"}"};
      std::uint32_t id = 0, channel = 0;
      std::string error;
      if (!uint32Of(item, "id", id, error, where) || !uint32Of(item, "channelId", channel, error, where))
        return ClientError{error};
      s.subscriptions.emplace_back(id, channel);
    }
    return s;
  }
  if (op == "unsubscribe") {
    const auto ids = j.find("subscriptionIds");
    if (ids == j.end() || !ids->is_array()) return ClientError{"unsubscribe: \"subscriptionIds\" must be an array"};
    Unsubscribe u;
    for (const json& id : *ids) {
      if (!id.is_number_integer() || id < 0 || id > std::numeric_limits<std::uint32_t>::max())
        return ClientError{"unsubscribe: \"subscriptionIds\" must hold integers in [0, 4294967295]"};
      u.subscription_ids.push_back(id.get<std::uint32_t>());
    }
    return u;
  }
  // Requests of the protocol this server has no capability for: said so, by name.
  static const std::vector<std::pair<std::string, std::string>> needs = {
      {"advertise", "clientPublish"},          {"unadvertise", "clientPublish"},
      {"getParameters", "parameters"},         {"setParameters", "parameters"},
      {"subscribeParameterUpdates", "parametersSubscribe"}, {"unsubscribeParameterUpdates", "parametersSubscribe"},
      {"subscribeConnectionGraph", "connectionGraph"},      {"unsubscribeConnectionGraph", "connectionGraph"},
      {"fetchAsset", "assets"}};
  for (const auto& [name, capability] : needs)
    if (op == name) return ClientError{"op '" + op + "' needs the capability '" + capability + "', which terramap does not offer"};
  return ClientError{"unknown op '" + clip(op) + "'" + didYouMean(op, {"subscribe", "unsubscribe"}) +
                     " (this server takes subscribe and unsubscribe)"};
}

std::string gridSchema() {
  json s = object({{"timestamp", timeSchema()},
                   {"frame_id", typed("string")},
                   {"pose", poseSchema()},
                   {"column_count", uinteger()},
                   {"cell_size", object({{"x", typed("number")}, {"y", typed("number")}}, {"x", "y"})},
                   {"row_stride", uinteger()},
                   {"cell_stride", uinteger()},
                   {"fields", fieldsSchema()},
                   {"data", bytesSchema()}},
                  {"timestamp", "frame_id", "pose", "column_count", "cell_size", "row_stride", "cell_stride", "fields",
                   "data"});
  s["title"] = "foxglove.Grid";
  return s.dump();
}

std::string pointCloudSchema() {
  json s = object({{"timestamp", timeSchema()},
                   {"frame_id", typed("string")},
                   {"pose", poseSchema()},
                   {"point_stride", uinteger()},
                   {"fields", fieldsSchema()},
                   {"data", bytesSchema()}},
                  {"timestamp", "frame_id", "pose", "point_stride", "fields", "data"});
  s["title"] = "foxglove.PointCloud";
  return s.dump();
}

std::uint64_t stampNs(double stamp_s) {
  if (!(stamp_s > 0)) return 0;
  if (stamp_s >= 1.8e10) return std::numeric_limits<std::uint64_t>::max();  // beyond uint64 ns (year 2540)
  return static_cast<std::uint64_t>(std::llround(stamp_s * 1e9));
}

std::string gridMessage(const LayeredMap& map, const std::vector<std::string>& layers, int stride, double stamp_s,
                        const std::string& frame_id) {
  const Geometry& g = map.geometry();
  std::vector<LayerId> ids;
  for (const std::string& name : layers) ids.push_back(map.layerId(name));
  const int nx = g.size().x(), ny = g.size().y();
  const int cols = (nx + stride - 1) / stride, rows = (ny + stride - 1) / stride;
  const int nl = static_cast<int>(ids.size());
  std::vector<float> cells(static_cast<std::size_t>(rows) * cols * nl);
  // Whole layers copied out tile by tile (readLayer) and gathered from there: far cheaper than
  // a bounds-checked at() per cell. One layer at a time, and only up to kMaxCopiedCells (64 MB):
  // a huge sparse map is read cell by cell at the sampled cells only, never copied whole.
  constexpr long kMaxCopiedCells = 16L << 20;
  if (static_cast<long>(nx) * ny > kMaxCopiedCells) {
    for (int r = 0; r < rows; ++r)
      for (int c = 0; c < cols; ++c)
        for (int k = 0; k < nl; ++k)
          cells[(static_cast<std::size_t>(r) * cols + c) * nl + k] = map.at(ids[k], Index(nx - 1 - c * stride, ny - 1 - r * stride));
  }
  std::vector<float> layer(static_cast<long>(nx) * ny > kMaxCopiedCells ? 0 : static_cast<std::size_t>(nx) * ny);
  for (int k = 0; k < nl && !layer.empty(); ++k) {
    map.readLayer(ids[k], layer.data(), nx, ny);
    for (int r = 0; r < rows; ++r) {
      // Logical cell (i, j) is layer[i + j * nx]; Grid (c, r) is (nx - 1 - c * stride, ny - 1 - r * stride).
      const float* src = &layer[static_cast<std::size_t>(ny - 1 - r * stride) * nx + (nx - 1)];
      float* out = &cells[static_cast<std::size_t>(r) * cols * nl + k];
      for (int c = 0; c < cols; ++c) out[static_cast<std::size_t>(c) * nl] = src[-static_cast<std::ptrdiff_t>(c) * stride];
    }
  }
  // Foxglove reads the bytes as little-endian float32, the byte order of every machine terramap builds for.
  static_assert(sizeof(float) == 4);
  json fields = json::array();
  for (int k = 0; k < nl; ++k) fields.push_back(float32Field(layers[k], 4 * k));
  const double res = g.resolution(), cell = stride * res;
  const Eigen::Vector3d corner(g.center().x() - 0.5 * nx * res, g.center().y() - 0.5 * ny * res, 0.0);
  json j = {{"timestamp", timeOf(stamp_s)},
            {"frame_id", frame_id},
            {"pose", poseOf(corner, Eigen::Quaterniond::Identity())},
            {"column_count", cols},
            {"cell_size", {{"x", cell}, {"y", cell}}},
            {"row_stride", 4 * nl * cols},
            {"cell_stride", 4 * nl},
            {"fields", fields}};
  return withData(j, base64(cells.data(), cells.size() * sizeof(float)));
}

std::string pointCloudMessage(const PointCloud& cloud, const std::string& frame_id) {
  static_assert(sizeof(PointXYZI) == 16, "x, y, z, intensity as four packed float32");
  json fields = json::array({float32Field("x", 0), float32Field("y", 4), float32Field("z", 8), float32Field("intensity", 12)});
  const Eigen::Quaterniond q(cloud.T_map_sensor.rotation());
  json j = {{"timestamp", timeOf(cloud.stamp)},
            {"frame_id", frame_id},
            {"pose", poseOf(cloud.T_map_sensor.translation(), q)},
            {"point_stride", 16},
            {"fields", fields}};
  return withData(j, base64(cloud.points.data(), cloud.points.size() * sizeof(PointXYZI)));
}

}  // namespace terramap::cli::foxglove

#pragma once
// The Foxglove WebSocket protocol (subprotocol `foxglove.websocket.v1`, the public spec of
// github.com/foxglove/ws-protocol) as `terramap serve` speaks it: the server's JSON messages,
// the binary Message Data head, the client's requests checked field by field, and the map and
// the latest cloud as `foxglove.Grid` and `foxglove.PointCloud` messages in JSON encoding
// (JSON Schema: binary fields as base64 strings, which Foxglove decodes by the schema's
// `contentEncoding`). Pure functions: no sockets here (live_server.cpp does the I/O).
#include <terramap/core/events.hpp>
#include <terramap/core/layered_map.hpp>

#include <array>
#include <cstdint>
#include <string>
#include <utility>
#include <variant>
#include <vector>

namespace terramap::cli::foxglove {

inline constexpr const char* kSubprotocol = "foxglove.websocket.v1";

/// A channel the server advertises: always JSON-encoded with a JSON Schema.
struct Channel {
  std::uint32_t id = 0;
  std::string topic;        ///< e.g. "/terramap/map"
  std::string schema_name;  ///< e.g. "foxglove.Grid"
  std::string schema;       ///< the JSON Schema text
};

/// Whether a Sec-WebSocket-Protocol header value (comma-separated tokens) offers kSubprotocol.
bool offersSubprotocol(const std::string& header_value);

/// {"op": "serverInfo", ...}: no capabilities (clients may subscribe, nothing else).
std::string serverInfo(const std::string& session_id);
/// {"op": "advertise", "channels": [...]}.
std::string advertise(const std::vector<Channel>& channels);
/// Status levels of the spec.
enum class Level { Info = 0, Warning = 1, Error = 2 };
/// {"op": "status", "level": L, "message": M} (and "id" when not empty).
std::string status(Level level, const std::string& message, const std::string& id = "");

/// The 13 bytes before a Message Data payload: opcode 0x01, the subscription id (uint32) and
/// the timestamp (uint64, nanoseconds), both little-endian.
std::array<char, 13> messageDataHead(std::uint32_t subscription_id, std::uint64_t timestamp_ns);

/// A client's request the server acts on. Every other request is an error (ClientError).
struct Subscribe {
  std::vector<std::pair<std::uint32_t, std::uint32_t>> subscriptions;  ///< (subscription id, channel id)
};
struct Unsubscribe {
  std::vector<std::uint32_t> subscription_ids;
};
struct ClientError {
  std::string message;  ///< what was wrong, quoting at most a short piece of the request
};
/// Parses one text message of a client. Never throws on any input.
std::variant<Subscribe, Unsubscribe, ClientError> parseClientMessage(const std::string& text);

/// The JSON Schemas of foxglove.Grid and foxglove.PointCloud (the fields and types of
/// Foxglove's message schemas, written here).
std::string gridSchema();
std::string pointCloudSchema();

/// Stamps in seconds (any epoch) as the spec's nanoseconds: negative or NaN -> 0.
std::uint64_t stampNs(double stamp_s);

/// `layers` of `map` as a foxglove.Grid in `frame_id` (the map frame): one float32 field per
/// layer, in the given order, cells interleaved; NaN = unknown, as in the map. Grid row r,
/// column c (row-major, the first row the map's southern edge, the first column its western
/// edge) holds logical cell (size.x - 1 - c * stride, size.y - 1 - r * stride); the cell size
/// is stride * resolution and the pose is the map's south-west corner at z = 0, axes along the
/// map's. \throws LayerError for an unknown layer.
std::string gridMessage(const LayeredMap& map, const std::vector<std::string>& layers, int stride, double stamp_s,
                        const std::string& frame_id);
/// A cloud as a foxglove.PointCloud in `frame_id` (the map frame): the points in the sensor
/// frame (x, y, z, intensity as float32) with the pose T_map_sensor, so nothing is transformed.
std::string pointCloudMessage(const PointCloud& cloud, const std::string& frame_id);

}  // namespace terramap::cli::foxglove

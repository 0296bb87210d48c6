#pragma once
// The HTTP + WebSocket server behind `terramap serve` (Boost.Beast on one Asio thread).
// It serves the files of one folder (the live view's page and its bundled libraries) and
// broadcasts binary frames on the WebSocket path /live; each client gets the newest frame only
// (a slow client skips frames instead of queueing them). A WebSocket on / that offers the
// subprotocol foxglove.websocket.v1 speaks the Foxglove WebSocket protocol instead
// (foxglove_ws.hpp): serverInfo and advertise of the channels, subscribe/unsubscribe, Message
// Data frames of the newest message per channel; a bad request is answered with a status.
//
// Any page the user has open, and anything that can reach the port, may talk to it, so
// (docs/reliability.md, "The live view"): a request resolves to a canonical path inside the
// root or is answered 404; Host must name the served address and Origin, when sent, must be
// the page's own (403 otherwise: other sites and DNS rebinding) or, for the Foxglove endpoint,
// one the user listed; connections and WebSocket message sizes are capped, both endpoints
// together; error pages name no path of the machine. It listens on 127.0.0.1 unless told
// otherwise.
#include <cstddef>
#include <cstdint>
#include <filesystem>
#include <functional>
#include <memory>
#include <string>
#include <vector>

namespace terramap::cli {

struct LiveServerOptions {
  std::string address = "127.0.0.1";  ///< an IP address literal to listen on
  std::uint16_t port = 0;             ///< 0 = a free port, see LiveServer::port()
  std::filesystem::path web_root;     ///< the folder whose files are served
  int max_connections = 32;           ///< open HTTP and WebSocket connections together
  std::size_t max_message_bytes = 4096;  ///< largest WebSocket message a client may send
  /// Origins (e.g. "https://app.foxglove.dev") besides the page's own that may open the
  /// Foxglove endpoint; clients that send no Origin (Foxglove's desktop app, scripts) may too.
  std::vector<std::string> foxglove_origins;
};

/// A channel advertised on the Foxglove endpoint (JSON encoding, JSON Schema).
struct FoxgloveChannel {
  std::string topic;
  std::string schema_name;
  std::string schema;
};

class LiveServer {
 public:
  /// Binds `o.address:o.port`. \throws OutputError if it cannot, ConfigError for a bad root.
  explicit LiveServer(LiveServerOptions o);
  ~LiveServer();
  LiveServer(const LiveServer&) = delete;
  LiveServer& operator=(const LiveServer&) = delete;

  std::uint16_t port() const;
  /// Called on the server thread with each text message a client sends; a non-empty result is
  /// sent back to that client as a text message (the error of a refused command).
  void onCommand(std::function<std::string(const std::string&)> f);
  /// Called on the server thread when a page opens the WebSocket.
  void onConnect(std::function<void()> f);
  /// Sends `frame` to every client, and to every client that connects later until the next
  /// publish. Thread-safe.
  void publish(std::string frame);
  /// The Foxglove endpoint's channels, ids 0, 1, ... in this order. Before run() only.
  void foxgloveChannels(std::vector<FoxgloveChannel> channels);
  /// Whether a Foxglove client is subscribed to channel `id` now. Thread-safe.
  bool foxgloveSubscribed(std::uint32_t id) const;
  /// Called on the server thread when a Foxglove client subscribes to channel `id` (the
  /// publisher then sends the current message, so a new subscriber need not wait for a change).
  void onFoxgloveSubscribe(std::function<void(std::uint32_t)> f);
  /// Sends `payload` (the message's JSON) on channel `id`, stamped `stamp_ns` (nanoseconds), to
  /// every subscriber of it; per client, the newest message of a channel replaces one that has
  /// not started to go out. Thread-safe.
  void publishFoxglove(std::uint32_t id, std::uint64_t stamp_ns, std::string payload);
  /// Sends a status message (foxglove_ws.hpp: level 0 info, 1 warning, 2 error) to every
  /// Foxglove client. Thread-safe.
  void foxgloveStatus(int level, std::string message, std::string id = "");
  /// Runs the server on the calling thread until stop().
  void run();
  /// Thread-safe; run() returns soon after.
  void stop();

  /// `{"error": message}`, the one shape of every refusal sent on the socket.
  static std::string errorMessage(const std::string& message);

  struct Impl;  // public only so the file's session classes can name it

 private:
  std::shared_ptr<Impl> impl_;
};

}  // namespace terramap::cli

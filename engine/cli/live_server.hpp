#pragma once
// The HTTP + WebSocket server behind `terramap serve` (Boost.Beast on one Asio thread).
// It serves the files of one folder (the live view's page and its bundled libraries) and
// broadcasts binary frames on the WebSocket path /live; each client gets the newest frame only
// (a slow client skips frames instead of queueing them).
//
// Any page the user has open, and anything that can reach the port, may talk to it, so
// (docs/reliability.md, "The live view"): a request resolves to a canonical path inside the
// root or is answered 404; Host must name the served address and Origin, when sent, must be
// the page's own (403 otherwise: other sites and DNS rebinding); connections and WebSocket
// message sizes are capped; error pages name no path of the machine. It listens on 127.0.0.1
// unless told otherwise.
#include <cstddef>
#include <cstdint>
#include <filesystem>
#include <functional>
#include <memory>
#include <string>

namespace terramap::cli {

struct LiveServerOptions {
  std::string address = "127.0.0.1";  ///< an IP address literal to listen on
  std::uint16_t port = 0;             ///< 0 = a free port, see LiveServer::port()
  std::filesystem::path web_root;     ///< the folder whose files are served
  int max_connections = 32;           ///< open HTTP and WebSocket connections together
  std::size_t max_message_bytes = 4096;  ///< largest WebSocket message a client may send
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

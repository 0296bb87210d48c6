#pragma once
// The HTTP + WebSocket server behind `terramap serve` (Boost.Beast on one Asio thread).
// It serves the files of one folder (the live view's page and its bundled libraries) and
// broadcasts binary frames on the WebSocket path /live; each client gets the newest frame only
// (a slow client skips frames instead of queueing them). Bound to 127.0.0.1 only.
#include <cstdint>
#include <filesystem>
#include <functional>
#include <memory>
#include <string>

namespace terramap::cli {

class LiveServer {
 public:
  /// Binds 127.0.0.1:`port` (0 = a free port, see port()). \throws OutputError if it cannot.
  LiveServer(std::uint16_t port, std::filesystem::path web_root);
  ~LiveServer();
  LiveServer(const LiveServer&) = delete;
  LiveServer& operator=(const LiveServer&) = delete;

  std::uint16_t port() const;
  /// Called on the server thread with each text message a client sends.
  void onCommand(std::function<void(const std::string&)> f);
  /// Called on the server thread when a page opens the WebSocket.
  void onConnect(std::function<void()> f);
  /// Sends `frame` to every client, and to every client that connects later until the next
  /// publish. Thread-safe.
  void publish(std::string frame);
  /// Runs the server on the calling thread until stop().
  void run();
  /// Thread-safe; run() returns soon after.
  void stop();

  struct Impl;  // public only so the file's session classes can name it

 private:
  std::shared_ptr<Impl> impl_;
};

}  // namespace terramap::cli

#include "live_server.hpp"

#include "foxglove_ws.hpp"

#include <terramap/core/error.hpp>

#include <boost/asio.hpp>
#include <boost/beast/core.hpp>
#include <boost/beast/http.hpp>
#include <boost/beast/websocket.hpp>
#include <nlohmann/json.hpp>

#include <unistd.h>

#include <algorithm>
#include <array>
#include <chrono>
#include <cstdio>
#include <deque>
#include <fstream>
#include <limits>
#include <map>
#include <mutex>
#include <optional>
#include <sstream>
#include <vector>

namespace terramap::cli {

namespace asio = boost::asio;
namespace beast = boost::beast;
namespace http = beast::http;
namespace websocket = beast::websocket;
using tcp = asio::ip::tcp;
namespace fs = std::filesystem;

namespace {

const char* contentType(const fs::path& p) {
  const std::string e = p.extension().string();
  if (e == ".html") return "text/html; charset=utf-8";
  if (e == ".js" || e == ".mjs") return "text/javascript; charset=utf-8";
  if (e == ".css") return "text/css";
  if (e == ".json") return "application/json";
  if (e == ".png") return "image/png";
  return "application/octet-stream";
}

/// Whether canonical `p` is `root` or below it, compared component by component (a string
/// prefix would let /srv/web-old pass for /srv/web).
bool insideRoot(const fs::path& root, const fs::path& p) {
  auto q = p.begin();
  for (auto r = root.begin(); r != root.end(); ++r, ++q)
    if (q == p.end() || *r != *q) return false;
  return true;
}

/// A request's Host header split into name and port ("[::1]:8765" -> "[::1]", "8765").
std::pair<std::string, std::string> splitHost(const std::string& h) {
  const std::size_t colon = h.rfind(':');
  if (colon == std::string::npos || (h.find(']') != std::string::npos && colon < h.find(']'))) return {h, ""};
  return {h.substr(0, colon), h.substr(colon + 1)};
}

bool isIpLiteral(std::string name) {
  if (name.size() > 2 && name.front() == '[' && name.back() == ']') name = name.substr(1, name.size() - 2);
  beast::error_code ec;
  (void)asio::ip::make_address(name, ec);
  return !ec;
}

}  // namespace

class WsSession;
class FoxgloveSession;

/// One open connection counted against max_connections; released when the session holding
/// it ends, however it ends.
struct ConnectionSlot {
  explicit ConnectionSlot(std::shared_ptr<LiveServer::Impl> s);
  ~ConnectionSlot();
  std::shared_ptr<LiveServer::Impl> srv;
};

struct LiveServer::Impl : std::enable_shared_from_this<LiveServer::Impl> {
  asio::io_context ioc{1};
  tcp::acceptor acceptor{ioc};
  LiveServerOptions opt;
  fs::path root;  // canonical
  asio::ip::address bound;
  std::function<std::string(const std::string&)> on_command;
  std::function<void()> on_connect;
  std::vector<std::weak_ptr<WsSession>> sessions;  // touched on the io thread only
  std::shared_ptr<const std::string> latest;       // likewise
  int connections = 0;                             // likewise
  std::vector<foxglove::Channel> fox_channels;     // fixed before run()
  std::string fox_advertise;                       // the advertise message of fox_channels
  std::string fox_session_id;                      // tells a client the server restarted
  std::function<void(std::uint32_t)> on_fox_subscribe;
  std::vector<std::weak_ptr<FoxgloveSession>> fox_sessions;  // io thread only
  mutable std::mutex fox_mu;                       // guards fox_subscribers (read by the publisher)
  std::vector<int> fox_subscribers;                // subscriptions per channel, all clients

  void accept();
  /// The file for a GET of `target`, or false (404): the target, with its leading slashes
  /// taken off, is resolved below the root (symbolic links and `..` included) and must land
  /// on a regular file inside it.
  bool readFile(const std::string& target, std::string& body, fs::path& path) const {
    std::string t = target.substr(0, target.find_first_of("?#"));
    if (t.empty() || t.front() != '/' || t.find('\0') != std::string::npos) return false;
    if (t == "/") t = "/index.html";
    t.erase(0, t.find_first_not_of('/'));
    const fs::path rel(t);
    if (rel.empty() || rel.has_root_path()) return false;
    std::error_code ec;
    path = fs::canonical(root / rel, ec);
    if (ec) return false;
    if (!insideRoot(root, path)) return false;
    if (!fs::is_regular_file(path, ec)) return false;
    std::ifstream f(path, std::ios::binary);
    std::ostringstream os;
    os << f.rdbuf();
    body = os.str();
    return static_cast<bool>(f) || f.eof();
  }
  /// Host must name this server: its port, and a name that cannot be rebound to another
  /// machine by DNS (an address literal, localhost on a loopback bind, this host's name on a
  /// public bind). Origin, which browsers always send for a WebSocket, must be the page's own.
  /// The Foxglove endpoint also admits the Origins the user listed (Foxglove's web app).
  bool allowed(const http::request<http::string_body>& req, bool foxglove = false) const {
    const auto host_it = req.find(http::field::host);
    if (host_it == req.end()) return false;
    const std::string host(host_it->value());
    const auto [name, port] = splitHost(host);
    if (port != std::to_string(acceptor.local_endpoint().port())) return false;
    bool name_ok = false;
    if (bound.is_unspecified()) {
      char self[256] = {};
      name_ok = isIpLiteral(name) || name == "localhost" || (::gethostname(self, sizeof self - 1) == 0 && name == self);
    } else {
      name_ok = name == bound.to_string() || (bound.is_v6() && name == "[" + bound.to_string() + "]") ||
                (bound.is_loopback() && name == "localhost");
    }
    if (!name_ok) return false;
    const auto origin = req.find(http::field::origin);
    if (origin == req.end() || std::string(origin->value()) == "http://" + host) return true;
    const auto& listed = opt.foxglove_origins;
    return foxglove && std::find(listed.begin(), listed.end(), std::string(origin->value())) != listed.end();
  }
  void join(const std::shared_ptr<WsSession>& s);
  void joinFoxglove(const std::shared_ptr<FoxgloveSession>& s);
  void countSubscriber(std::uint32_t channel, int delta) {
    std::lock_guard<std::mutex> lock(fox_mu);
    fox_subscribers.at(channel) += delta;
  }
  void broadcast(std::shared_ptr<const std::string> frame);
};

ConnectionSlot::ConnectionSlot(std::shared_ptr<LiveServer::Impl> s) : srv(std::move(s)) { ++srv->connections; }
ConnectionSlot::~ConnectionSlot() { --srv->connections; }

std::string LiveServer::errorMessage(const std::string& message) {
  return nlohmann::json{{"error", message}}.dump();
}

class WsSession : public std::enable_shared_from_this<WsSession> {
 public:
  WsSession(tcp::socket&& socket, std::shared_ptr<ConnectionSlot> slot)
      : ws_(std::move(socket)), slot_(std::move(slot)), srv_(slot_->srv) {}

  void start(http::request<http::string_body> req) {
    ws_.set_option(websocket::stream_base::timeout::suggested(beast::role_type::server));
    // Beyond this a read fails and the socket is closed with 1009 (message too big).
    ws_.read_message_max(srv_->opt.max_message_bytes);
    ws_.binary(true);
    ws_.async_accept(req, [self = shared_from_this()](beast::error_code ec) {
      if (ec) return;
      self->srv_->join(self);
      self->read();
    });
  }

  /// On the io thread: the newest frame replaces one that has not started to go out.
  void send(std::shared_ptr<const std::string> frame) {
    frame_ = std::move(frame);
    if (!writing_) write();
  }

 private:
  static constexpr std::size_t kMaxQueuedReplies = 16;

  void read() {
    ws_.async_read(buf_, [self = shared_from_this()](beast::error_code ec, std::size_t) {
      if (ec) return;  // closed (or too big: Beast has sent the close): the weak pointer expires
      const std::string text = beast::buffers_to_string(self->buf_.data());
      self->buf_.consume(self->buf_.size());
      std::string reply;
      if (!self->ws_.got_text()) {
        reply = LiveServer::errorMessage("a command is a JSON text message, not binary");
      } else if (self->srv_->on_command) {
        // Nothing a client sends may end the server: a command that throws is its error.
        try {
          reply = self->srv_->on_command(text);
        } catch (const std::exception& e) {
          reply = LiveServer::errorMessage(std::string("command failed: ") + e.what());
        } catch (...) {
          reply = LiveServer::errorMessage("command failed");
        }
      }
      if (!reply.empty() && self->replies_.size() < kMaxQueuedReplies) {
        self->replies_.push_back(std::make_shared<const std::string>(std::move(reply)));
        if (!self->writing_) self->write();
      }
      self->read();
    });
  }
  /// Replies first (they are never dropped), then the newest frame.
  void write() {
    std::shared_ptr<const std::string> out;
    bool text = false;
    if (!replies_.empty()) {
      out = std::move(replies_.front());
      replies_.pop_front();
      text = true;
    } else if (frame_) {
      out = std::move(frame_);
      frame_.reset();
    } else {
      return;
    }
    writing_ = true;
    ws_.text(text);
    ws_.async_write(asio::buffer(*out), [self = shared_from_this(), out](beast::error_code ec, std::size_t) {
      self->writing_ = false;
      if (!ec) self->write();
    });
  }

  websocket::stream<beast::tcp_stream> ws_;
  beast::flat_buffer buf_;
  std::deque<std::shared_ptr<const std::string>> replies_;
  std::shared_ptr<const std::string> frame_;
  bool writing_ = false;
  std::shared_ptr<ConnectionSlot> slot_;
  std::shared_ptr<LiveServer::Impl> srv_;
};

/// A Foxglove client: serverInfo and advertise on connect, then subscribe/unsubscribe requests
/// in, Message Data frames out. Replies (status, info) are never dropped; of the data, only the
/// newest message per channel waits, so a slow client skips messages instead of queueing them.
class FoxgloveSession : public std::enable_shared_from_this<FoxgloveSession> {
 public:
  FoxgloveSession(tcp::socket&& socket, std::shared_ptr<ConnectionSlot> slot)
      : ws_(std::move(socket)), slot_(std::move(slot)), srv_(slot_->srv) {}
  ~FoxgloveSession() {
    for (const auto& [sub, channel] : subs_) srv_->countSubscriber(channel, -1);
  }

  void start(http::request<http::string_body> req) {
    ws_.set_option(websocket::stream_base::timeout::suggested(beast::role_type::server));
    ws_.set_option(websocket::stream_base::decorator([](websocket::response_type& res) {
      res.set(http::field::sec_websocket_protocol, foxglove::kSubprotocol);
      res.set(http::field::server, "terramap");
    }));
    ws_.read_message_max(srv_->opt.max_message_bytes);
    ws_.async_accept(req, [self = shared_from_this()](beast::error_code ec) {
      if (ec) return;
      self->reply(foxglove::serverInfo(self->srv_->fox_session_id));
      self->reply(self->srv_->fox_advertise);
      self->srv_->joinFoxglove(self);
      self->read();
    });
  }

  /// On the io thread: the newest message of `channel` for this client, if it subscribed.
  void send(std::uint32_t channel, std::uint64_t stamp_ns, std::shared_ptr<const std::string> payload) {
    for (const auto& [sub, ch] : subs_)
      if (ch == channel) {
        pending_[channel] = Pending{foxglove::messageDataHead(sub, stamp_ns), std::move(payload)};
        if (!writing_) write();
        return;
      }
  }
  void reply(std::string text) {
    if (replies_.size() >= kMaxQueuedReplies) return;  // a client flooding requests loses answers, not memory
    replies_.push_back(std::make_shared<const std::string>(std::move(text)));
    if (!writing_) write();
  }

 private:
  static constexpr std::size_t kMaxQueuedReplies = 16;
  struct Pending {
    std::array<char, 13> head;
    std::shared_ptr<const std::string> payload;
  };

  void read() {
    ws_.async_read(buf_, [self = shared_from_this()](beast::error_code ec, std::size_t) {
      if (ec) return;  // closed, or too big (Beast has sent the close 1009)
      const std::string text = beast::buffers_to_string(self->buf_.data());
      self->buf_.consume(self->buf_.size());
      if (!self->ws_.got_text())
        self->reply(foxglove::status(foxglove::Level::Error,
                                     "binary client messages need the capability 'clientPublish' or 'services', "
                                     "which terramap does not offer"));
      else
        self->handle(text);
      self->read();
    });
  }

  void handle(const std::string& text) {
    const auto request = foxglove::parseClientMessage(text);
    if (const auto* e = std::get_if<foxglove::ClientError>(&request)) {
      reply(foxglove::status(foxglove::Level::Error, e->message));
      return;
    }
    std::string problems;
    auto problem = [&](const std::string& p) { problems += (problems.empty() ? "" : "; ") + p; };
    if (const auto* s = std::get_if<foxglove::Subscribe>(&request)) {
      for (const auto& [sub, channel] : s->subscriptions) {
        if (channel >= srv_->fox_channels.size()) {
          problem("subscribe: no channel " + std::to_string(channel));
        } else if (subs_.count(sub)) {
          problem("subscribe: subscription id " + std::to_string(sub) + " is in use");
        } else if (std::any_of(subs_.begin(), subs_.end(), [&](const auto& kv) { return kv.second == channel; })) {
          problem("subscribe: channel " + std::to_string(channel) + " is already subscribed");
        } else if (subs_.size() >= srv_->fox_channels.size()) {
          problem("subscribe: too many subscriptions");
        } else {
          subs_[sub] = channel;
          srv_->countSubscriber(channel, +1);
          if (srv_->on_fox_subscribe) srv_->on_fox_subscribe(channel);
        }
      }
    } else if (const auto* u = std::get_if<foxglove::Unsubscribe>(&request)) {
      for (const std::uint32_t sub : u->subscription_ids) {
        const auto it = subs_.find(sub);
        if (it == subs_.end()) {
          problem("unsubscribe: no subscription " + std::to_string(sub));
          continue;
        }
        pending_.erase(it->second);
        srv_->countSubscriber(it->second, -1);
        subs_.erase(it);
      }
    }
    if (!problems.empty()) reply(foxglove::status(foxglove::Level::Error, problems.size() <= 512 ? problems : problems.substr(0, 512) + "..."));
  }

  void write() {
    writing_ = true;
    if (!replies_.empty()) {
      auto out = std::move(replies_.front());
      replies_.pop_front();
      ws_.text(true);
      ws_.async_write(asio::buffer(*out), [self = shared_from_this(), out](beast::error_code ec, std::size_t) {
        self->writing_ = false;
        if (!ec) self->write();
      });
      return;
    }
    if (pending_.empty()) {
      writing_ = false;
      return;
    }
    // Channels take turns (the lowest id after the one sent last), so a big map cannot starve the cloud.
    auto it = pending_.upper_bound(last_channel_);
    if (it == pending_.end()) it = pending_.begin();
    last_channel_ = it->first;
    auto msg = std::make_shared<Pending>(std::move(it->second));
    pending_.erase(it);
    ws_.binary(true);
    const std::array<asio::const_buffer, 2> bufs{asio::buffer(msg->head), asio::buffer(*msg->payload)};
    ws_.async_write(bufs, [self = shared_from_this(), msg](beast::error_code ec, std::size_t) {
      self->writing_ = false;
      if (!ec) self->write();
    });
  }

  websocket::stream<beast::tcp_stream> ws_;
  beast::flat_buffer buf_;
  std::deque<std::shared_ptr<const std::string>> replies_;
  std::map<std::uint32_t, Pending> pending_;           // by channel
  std::map<std::uint32_t, std::uint32_t> subs_;        // subscription id -> channel
  std::uint32_t last_channel_ = std::numeric_limits<std::uint32_t>::max();
  bool writing_ = false;
  std::shared_ptr<ConnectionSlot> slot_;
  std::shared_ptr<LiveServer::Impl> srv_;
};

namespace {

/// A Foxglove app that sends an Origin is refused until the user lists it: say which, on the
/// console (the refused client learns nothing). Printable ASCII only, clipped, at most 20 times.
void noteRefusedOrigin(const http::request<http::string_body>& req) {
  static int told = 0;
  const auto origin = req.find(http::field::origin);
  if (origin == req.end() || told >= 20) return;
  ++told;
  std::string o(origin->value().substr(0, 100));
  for (char& ch : o)
    if (ch < 0x20 || ch > 0x7e) ch = '?';
  std::fprintf(stderr, "terramap serve: refused a Foxglove connection from Origin %s (if that is yours: --foxglove-origin %s)\n",
               o.c_str(), o.c_str());
}

class HttpSession : public std::enable_shared_from_this<HttpSession> {
 public:
  HttpSession(tcp::socket&& socket, std::shared_ptr<ConnectionSlot> slot)
      : stream_(std::move(socket)), slot_(std::move(slot)), srv_(slot_->srv) {}
  void start() {
    stream_.expires_after(std::chrono::seconds(30));
    // A page asks with a short GET: no request of this server has a body.
    parser_.header_limit(8192);
    parser_.body_limit(1024);
    http::async_read(stream_, buf_, parser_, [self = shared_from_this()](beast::error_code ec, std::size_t) {
      if (!ec) self->handle();
    });
  }

 private:
  void handle() {
    http::request<http::string_body> req = parser_.release();
    auto res = std::make_shared<http::response<http::string_body>>();
    res->version(req.version());
    res->keep_alive(false);
    res->set(http::field::server, "terramap");
    // Nothing is fetched from elsewhere: the page and its libraries are all served from here.
    res->set(http::field::cache_control, "no-store");
    res->set(http::field::content_type, "text/plain");
    // Error pages are fixed texts: nothing of the request or of the machine is echoed.
    std::string body;
    fs::path path;
    const bool upgrade = websocket::is_upgrade(req);
    const auto protocols = req.find(http::field::sec_websocket_protocol);
    const bool foxglove = upgrade && req.target() == "/" && protocols != req.end() &&
                          foxglove::offersSubprotocol(std::string(protocols->value()));
    if (!srv_->allowed(req, foxglove)) {
      res->result(http::status::forbidden);
      res->body() = "forbidden: Host or Origin is not this server\n";
      if (foxglove) {
        http::request<http::string_body> without_origin = req;
        without_origin.erase(http::field::origin);
        if (srv_->allowed(without_origin, true)) noteRefusedOrigin(req);  // the Origin was the reason
      }
    } else if (foxglove) {
      stream_.expires_never();
      std::make_shared<FoxgloveSession>(stream_.release_socket(), slot_)->start(std::move(req));
      return;
    } else if (upgrade) {
      if (req.target() == "/live") {
        stream_.expires_never();
        std::make_shared<WsSession>(stream_.release_socket(), slot_)->start(std::move(req));
        return;
      }
      res->result(http::status::not_found);
      res->body() = "not found\n";
    } else if (req.method() != http::verb::get) {
      res->result(http::status::method_not_allowed);
      res->body() = "method not allowed\n";
    } else if (srv_->readFile(std::string(req.target()), body, path)) {
      res->result(http::status::ok);
      res->set(http::field::content_type, contentType(path));
      res->body() = std::move(body);
    } else {
      res->result(http::status::not_found);
      res->body() = "not found\n";
    }
    res->prepare_payload();
    http::async_write(stream_, *res, [self = shared_from_this(), res](beast::error_code, std::size_t) {
      beast::error_code ec;
      self->stream_.socket().shutdown(tcp::socket::shutdown_send, ec);
    });
  }

  beast::tcp_stream stream_;
  beast::flat_buffer buf_;
  http::request_parser<http::string_body> parser_;
  std::shared_ptr<ConnectionSlot> slot_;
  std::shared_ptr<LiveServer::Impl> srv_;
};

}  // namespace

void LiveServer::Impl::accept() {
  acceptor.async_accept(asio::make_strand(ioc), [self = shared_from_this()](beast::error_code ec, tcp::socket s) {
    if (!self->acceptor.is_open()) return;
    if (!ec && self->connections >= self->opt.max_connections) {
      // Refused at once: a short fixed answer fits the socket's buffer, so this cannot block.
      static const std::string busy =
          "HTTP/1.1 503 Service Unavailable\r\nContent-Type: text/plain\r\nContent-Length: 29\r\n"
          "Connection: close\r\n\r\ntoo many connections, retry\r\n";
      beast::error_code wec;
      asio::write(s, asio::buffer(busy), wec);
      s.shutdown(tcp::socket::shutdown_both, wec);
      s.close(wec);
    } else if (!ec) {
      std::make_shared<HttpSession>(std::move(s), std::make_shared<ConnectionSlot>(self))->start();
    }
    self->accept();
  });
}

void LiveServer::Impl::join(const std::shared_ptr<WsSession>& s) {
  sessions.push_back(s);
  if (latest) s->send(latest);
  if (on_connect) on_connect();
}

void LiveServer::Impl::joinFoxglove(const std::shared_ptr<FoxgloveSession>& s) {
  fox_sessions.erase(std::remove_if(fox_sessions.begin(), fox_sessions.end(), [](const auto& w) { return w.expired(); }),
                     fox_sessions.end());
  fox_sessions.push_back(s);
  if (on_connect) on_connect();
}

void LiveServer::Impl::broadcast(std::shared_ptr<const std::string> frame) {
  latest = frame;
  std::vector<std::weak_ptr<WsSession>> alive;
  for (auto& w : sessions)
    if (auto s = w.lock()) {
      s->send(frame);
      alive.push_back(w);
    }
  sessions = std::move(alive);
}

LiveServer::LiveServer(LiveServerOptions o) : impl_(std::make_shared<Impl>()) {
  impl_->fox_session_id = std::to_string(std::chrono::system_clock::now().time_since_epoch().count());
  impl_->fox_advertise = foxglove::advertise({});
  std::error_code fec;
  impl_->root = fs::canonical(o.web_root, fec);
  if (fec) throw ConfigError("the live view's page folder " + o.web_root.string() + ": " + fec.message());
  impl_->opt = std::move(o);
  const LiveServerOptions& opt = impl_->opt;
  beast::error_code ec;
  impl_->bound = asio::ip::make_address(opt.address, ec);
  if (ec) throw ConfigError("cannot listen on '" + opt.address + "': not an IP address (" + ec.message() + ")");
  const tcp::endpoint ep(impl_->bound, opt.port);
  impl_->acceptor.open(ep.protocol(), ec);
  if (!ec) impl_->acceptor.set_option(asio::socket_base::reuse_address(true), ec);
  if (!ec) impl_->acceptor.bind(ep, ec);
  if (!ec) impl_->acceptor.listen(asio::socket_base::max_listen_connections, ec);
  if (ec) throw OutputError("cannot listen on " + opt.address + ":" + std::to_string(opt.port) + ": " + ec.message());
}

LiveServer::~LiveServer() { stop(); }

std::uint16_t LiveServer::port() const { return impl_->acceptor.local_endpoint().port(); }

void LiveServer::onCommand(std::function<std::string(const std::string&)> f) { impl_->on_command = std::move(f); }
void LiveServer::onConnect(std::function<void()> f) { impl_->on_connect = std::move(f); }

void LiveServer::foxgloveChannels(std::vector<FoxgloveChannel> channels) {
  impl_->fox_channels.clear();
  for (auto& c : channels)
    impl_->fox_channels.push_back(foxglove::Channel{static_cast<std::uint32_t>(impl_->fox_channels.size()), std::move(c.topic),
                                                    std::move(c.schema_name), std::move(c.schema)});
  impl_->fox_advertise = foxglove::advertise(impl_->fox_channels);
  std::lock_guard<std::mutex> lock(impl_->fox_mu);
  impl_->fox_subscribers.assign(impl_->fox_channels.size(), 0);
}

bool LiveServer::foxgloveSubscribed(std::uint32_t id) const {
  std::lock_guard<std::mutex> lock(impl_->fox_mu);
  return id < impl_->fox_subscribers.size() && impl_->fox_subscribers[id] > 0;
}

void LiveServer::onFoxgloveSubscribe(std::function<void(std::uint32_t)> f) { impl_->on_fox_subscribe = std::move(f); }

void LiveServer::publishFoxglove(std::uint32_t id, std::uint64_t stamp_ns, std::string payload) {
  auto p = std::make_shared<const std::string>(std::move(payload));
  asio::post(impl_->ioc, [impl = impl_, id, stamp_ns, p] {
    for (const auto& w : impl->fox_sessions)
      if (auto s = w.lock()) s->send(id, stamp_ns, p);
  });
}

void LiveServer::foxgloveStatus(int level, std::string message, std::string id) {
  const std::string text = foxglove::status(static_cast<foxglove::Level>(std::clamp(level, 0, 2)), message, id);
  asio::post(impl_->ioc, [impl = impl_, text] {
    for (const auto& w : impl->fox_sessions)
      if (auto s = w.lock()) s->reply(text);
  });
}

void LiveServer::publish(std::string frame) {
  auto f = std::make_shared<const std::string>(std::move(frame));
  asio::post(impl_->ioc, [impl = impl_, f] { impl->broadcast(f); });
}

void LiveServer::run() {
  impl_->accept();
  impl_->ioc.run();
}

void LiveServer::stop() {
  asio::post(impl_->ioc, [impl = impl_] {
    beast::error_code ec;
    impl->acceptor.close(ec);
    impl->ioc.stop();
  });
}

}  // namespace terramap::cli

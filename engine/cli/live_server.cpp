#include "live_server.hpp"

#include <terramap/core/error.hpp>

#include <boost/asio.hpp>
#include <boost/beast/core.hpp>
#include <boost/beast/http.hpp>
#include <boost/beast/websocket.hpp>

#include <deque>
#include <fstream>
#include <mutex>
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

}  // namespace

class WsSession;

struct LiveServer::Impl : std::enable_shared_from_this<LiveServer::Impl> {
  asio::io_context ioc{1};
  tcp::acceptor acceptor{ioc};
  fs::path root;
  std::function<void(const std::string&)> on_command;
  std::function<void()> on_connect;
  std::vector<std::weak_ptr<WsSession>> sessions;  // touched on the io thread only
  std::shared_ptr<const std::string> latest;       // likewise

  void accept();
  /// The file for a GET of `target`, or nullopt (404). Never leaves `root`.
  bool readFile(const std::string& target, std::string& body, fs::path& path) const {
    std::string t = target.substr(0, target.find('?'));
    if (t.empty() || t == "/") t = "/index.html";
    if (t.find("..") != std::string::npos) return false;
    path = root / t.substr(1);
    std::error_code ec;
    if (!fs::is_regular_file(path, ec)) return false;
    std::ifstream f(path, std::ios::binary);
    std::ostringstream os;
    os << f.rdbuf();
    body = os.str();
    return static_cast<bool>(f) || f.eof();
  }
  void join(const std::shared_ptr<WsSession>& s);
  void broadcast(std::shared_ptr<const std::string> frame);
};

class WsSession : public std::enable_shared_from_this<WsSession> {
 public:
  WsSession(tcp::socket&& socket, std::shared_ptr<LiveServer::Impl> srv) : ws_(std::move(socket)), srv_(std::move(srv)) {}

  void start(http::request<http::string_body> req) {
    ws_.set_option(websocket::stream_base::timeout::suggested(beast::role_type::server));
    ws_.binary(true);
    ws_.async_accept(req, [self = shared_from_this()](beast::error_code ec) {
      if (ec) return;
      self->srv_->join(self);
      self->read();
    });
  }

  /// On the io thread: queue the newest frame, dropping one that has not started to go out.
  void send(std::shared_ptr<const std::string> frame) {
    if (writing_ && queue_.size() > 1) queue_.pop_back();
    if (!writing_) queue_.clear();
    queue_.push_back(std::move(frame));
    if (!writing_) write();
  }

 private:
  void read() {
    ws_.async_read(buf_, [self = shared_from_this()](beast::error_code ec, std::size_t) {
      if (ec) return;  // closed: the weak pointer in the server expires
      const std::string text = beast::buffers_to_string(self->buf_.data());
      self->buf_.consume(self->buf_.size());
      if (self->srv_->on_command) self->srv_->on_command(text);
      self->read();
    });
  }
  void write() {
    writing_ = true;
    ws_.async_write(asio::buffer(*queue_.front()), [self = shared_from_this()](beast::error_code ec, std::size_t) {
      self->queue_.pop_front();
      self->writing_ = false;
      if (!ec && !self->queue_.empty()) self->write();
    });
  }

  websocket::stream<beast::tcp_stream> ws_;
  beast::flat_buffer buf_;
  std::deque<std::shared_ptr<const std::string>> queue_;
  bool writing_ = false;
  std::shared_ptr<LiveServer::Impl> srv_;
};

namespace {

class HttpSession : public std::enable_shared_from_this<HttpSession> {
 public:
  HttpSession(tcp::socket&& socket, std::shared_ptr<LiveServer::Impl> srv) : stream_(std::move(socket)), srv_(std::move(srv)) {}
  void start() {
    stream_.expires_after(std::chrono::seconds(30));
    http::async_read(stream_, buf_, req_, [self = shared_from_this()](beast::error_code ec, std::size_t) {
      if (!ec) self->handle();
    });
  }

 private:
  void handle() {
    if (websocket::is_upgrade(req_)) {
      if (req_.target() == "/live") {
        stream_.expires_never();
        std::make_shared<WsSession>(stream_.release_socket(), srv_)->start(std::move(req_));
      }
      return;
    }
    auto res = std::make_shared<http::response<http::string_body>>();
    res->version(req_.version());
    res->keep_alive(false);
    res->set(http::field::server, "terramap");
    // Nothing is fetched from elsewhere: the page and its libraries are all served from here.
    res->set(http::field::cache_control, "no-store");
    std::string body;
    fs::path path;
    if (req_.method() != http::verb::get) {
      res->result(http::status::method_not_allowed);
    } else if (srv_->readFile(std::string(req_.target()), body, path)) {
      res->result(http::status::ok);
      res->set(http::field::content_type, contentType(path));
      res->body() = std::move(body);
    } else {
      res->result(http::status::not_found);
      res->set(http::field::content_type, "text/plain");
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
  http::request<http::string_body> req_;
  std::shared_ptr<LiveServer::Impl> srv_;
};

}  // namespace

void LiveServer::Impl::accept() {
  acceptor.async_accept(asio::make_strand(ioc), [self = shared_from_this()](beast::error_code ec, tcp::socket s) {
    if (!self->acceptor.is_open()) return;
    if (!ec) std::make_shared<HttpSession>(std::move(s), self)->start();
    self->accept();
  });
}

void LiveServer::Impl::join(const std::shared_ptr<WsSession>& s) {
  sessions.push_back(s);
  if (latest) s->send(latest);
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

LiveServer::LiveServer(std::uint16_t port, fs::path web_root) : impl_(std::make_shared<Impl>()) {
  impl_->root = std::move(web_root);
  beast::error_code ec;
  const tcp::endpoint ep(asio::ip::make_address("127.0.0.1"), port);
  impl_->acceptor.open(ep.protocol(), ec);
  if (!ec) impl_->acceptor.set_option(asio::socket_base::reuse_address(true), ec);
  if (!ec) impl_->acceptor.bind(ep, ec);
  if (!ec) impl_->acceptor.listen(asio::socket_base::max_listen_connections, ec);
  if (ec) throw OutputError("cannot listen on 127.0.0.1:" + std::to_string(port) + ": " + ec.message());
}

LiveServer::~LiveServer() { stop(); }

std::uint16_t LiveServer::port() const { return impl_->acceptor.local_endpoint().port(); }

void LiveServer::onCommand(std::function<void(const std::string&)> f) { impl_->on_command = std::move(f); }
void LiveServer::onConnect(std::function<void()> f) { impl_->on_connect = std::move(f); }

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

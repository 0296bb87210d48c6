// `terramap serve` driven by a raw socket client, as a hostile page or a careless script would
// (docs/reliability.md): paths outside the web root, malformed WebSocket commands, foreign Origin and Host
// headers, too many connections, oversized messages, a public bind without the flag.
// Loopback only; every socket read has a timeout and the server is killed at the end.
#include "cli_util.hpp"

#include <gtest/gtest.h>

#include <arpa/inet.h>
#include <fcntl.h>
#include <netinet/in.h>
#include <poll.h>
#include <signal.h>
#include <sys/socket.h>
#include <sys/wait.h>
#include <unistd.h>

#include <chrono>
#include <cstring>
#include <regex>
#include <string>
#include <thread>
#include <vector>

using namespace terramap_test;

namespace {

const std::string kPipeline = std::string(TERRAMAP_SOURCE_DIR) + "/tests/web/live_pipeline.yaml";
constexpr const char* kSecret = "terramap-secret-8d1f";

/// `terramap serve` in a child process, on a free port, with a web root of two dummy files and
/// a secret file beside (not inside) the root.
class Server {
 public:
  explicit Server(const std::string& name, const std::vector<std::string>& extra = {}) {
    dir_ = tempDir("serve_" + name);
    root_ = dir_ / "web";
    fs::create_directories(root_);
    write(root_ / "index.html", "<html>live view</html>");
    write(root_ / "three.module.js", "// three");
    write(dir_ / "secret.txt", kSecret);
    fs::create_symlink(dir_ / "secret.txt", root_ / "link.txt");
    int out[2];
    if (pipe(out) != 0) throw std::runtime_error("pipe");
    std::vector<std::string> args = {kBin, "serve", kPipeline, "--port", "0", "--wait-for-viewer",
                                     "--web-root", root_.string()};
    args.insert(args.end(), extra.begin(), extra.end());
    pid_ = fork();
    if (pid_ == 0) {
      dup2(out[1], 1);
      dup2(out[1], 2);
      close(out[0]);
      setenv("TERRAMAP_PLUGIN_PATH", "", 1);
      std::vector<char*> argv;
      for (auto& a : args) argv.push_back(a.data());
      argv.push_back(nullptr);
      execv(argv[0], argv.data());
      _exit(127);
    }
    close(out[1]);
    out_fd_ = out[0];
    const auto deadline = std::chrono::steady_clock::now() + std::chrono::seconds(60);
    const std::regex serving("serving http://([0-9.]+):([0-9]+)/");
    while (std::chrono::steady_clock::now() < deadline) {
      pollfd p{out_fd_, POLLIN, 0};
      if (poll(&p, 1, 200) > 0) {
        char buf[4096];
        const ssize_t n = read(out_fd_, buf, sizeof buf);
        if (n <= 0) break;
        output_.append(buf, static_cast<size_t>(n));
        std::smatch m;
        if (std::regex_search(output_, m, serving)) {
          host_ = m[1];
          port_ = std::stoi(m[2]);
          return;
        }
      }
    }
  }
  ~Server() {
    if (pid_ > 0) {
      kill(pid_, SIGKILL);
      waitpid(pid_, nullptr, 0);
    }
    if (out_fd_ >= 0) close(out_fd_);
    std::error_code ec;
    fs::remove_all(dir_, ec);
  }
  int port() const { return port_; }
  const std::string& host() const { return host_; }
  const fs::path& root() const { return root_; }
  const fs::path& dir() const { return dir_; }
  std::string output() const { return output_; }
  /// Still running (not exited, not killed by std::terminate).
  bool alive() const { return pid_ > 0 && waitpid(pid_, nullptr, WNOHANG) == 0; }
  std::string hostHeader() const { return "127.0.0.1:" + std::to_string(port_); }

 private:
  fs::path dir_, root_;
  pid_t pid_ = -1;
  int out_fd_ = -1;
  int port_ = -1;
  std::string host_, output_;
};

/// A loopback TCP connection with a 5 s receive timeout.
class Conn {
 public:
  explicit Conn(int port) {
    fd_ = socket(AF_INET, SOCK_STREAM, 0);
    timeval tv{5, 0};
    setsockopt(fd_, SOL_SOCKET, SO_RCVTIMEO, &tv, sizeof tv);
    setsockopt(fd_, SOL_SOCKET, SO_SNDTIMEO, &tv, sizeof tv);
    sockaddr_in a{};
    a.sin_family = AF_INET;
    a.sin_port = htons(static_cast<std::uint16_t>(port));
    a.sin_addr.s_addr = htonl(INADDR_LOOPBACK);
    ok_ = connect(fd_, reinterpret_cast<sockaddr*>(&a), sizeof a) == 0;
  }
  ~Conn() { close(fd_); }
  bool ok() const { return ok_; }
  bool send(const std::string& s) {
    size_t off = 0;
    while (off < s.size()) {
      const ssize_t n = ::send(fd_, s.data() + off, s.size() - off, MSG_NOSIGNAL);
      if (n <= 0) return false;
      off += static_cast<size_t>(n);
    }
    return true;
  }
  /// Up to `n` bytes (fewer at EOF or timeout).
  std::string recvExactly(size_t n) {
    std::string s;
    while (s.size() < n) {
      char buf[65536];
      const ssize_t k = ::recv(fd_, buf, std::min(sizeof buf, n - s.size()), 0);
      if (k <= 0) break;
      s.append(buf, static_cast<size_t>(k));
    }
    return s;
  }
  /// Everything until the peer closes (or the timeout).
  std::string recvAll() {
    std::string s;
    char buf[65536];
    ssize_t k;
    while ((k = ::recv(fd_, buf, sizeof buf, 0)) > 0) s.append(buf, static_cast<size_t>(k));
    return s;
  }
  /// The response head, up to and including the blank line.
  std::string recvHead() {
    std::string s;
    char c;
    while (s.find("\r\n\r\n") == std::string::npos && ::recv(fd_, &c, 1, 0) == 1) s += c;
    return s;
  }

 private:
  int fd_ = -1;
  bool ok_ = false;
};

std::string get(int port, const std::string& target, const std::string& host) {
  Conn c(port);
  if (!c.ok()) return "";
  c.send("GET " + target + " HTTP/1.1\r\nHost: " + host + "\r\nConnection: close\r\n\r\n");
  return c.recvAll();
}

std::string status(const std::string& response) { return response.substr(0, response.find("\r\n")); }

std::string upgradeRequest(const std::string& host, const std::string& origin) {
  std::string r = "GET /live HTTP/1.1\r\nHost: " + host +
                  "\r\nUpgrade: websocket\r\nConnection: Upgrade\r\nSec-WebSocket-Key: dGhlIHNhbXBsZSBub25jZQ==\r\n"
                  "Sec-WebSocket-Version: 13\r\n";
  if (!origin.empty()) r += "Origin: " + origin + "\r\n";
  return r + "\r\n";
}

/// A client frame (always masked, as RFC 6455 requires of clients).
std::string frame(const std::string& payload, int opcode = 1) {
  std::string f;
  f += static_cast<char>(0x80 | opcode);
  const size_t n = payload.size();
  if (n < 126) {
    f += static_cast<char>(0x80 | n);
  } else if (n < 65536) {
    f += static_cast<char>(0x80 | 126);
    f += static_cast<char>(n >> 8);
    f += static_cast<char>(n & 0xff);
  } else {
    f += static_cast<char>(0x80 | 127);
    for (int i = 7; i >= 0; --i) f += static_cast<char>((static_cast<std::uint64_t>(n) >> (8 * i)) & 0xff);
  }
  const unsigned char mask[4] = {0x12, 0x34, 0x56, 0x78};
  for (unsigned char m : mask) f += static_cast<char>(m);
  for (size_t i = 0; i < n; ++i) f += static_cast<char>(payload[i] ^ mask[i % 4]);
  return f;
}

struct Frame {
  int opcode = -1;  // -1: the connection ended or timed out
  std::string payload;
};

Frame readFrame(Conn& c) {
  Frame f;
  const std::string h = c.recvExactly(2);
  if (h.size() < 2) return f;
  const int op = static_cast<unsigned char>(h[0]) & 0x0f;
  std::uint64_t n = static_cast<unsigned char>(h[1]) & 0x7f;
  if (n == 126) {
    const std::string e = c.recvExactly(2);
    if (e.size() < 2) return f;
    n = (static_cast<std::uint64_t>(static_cast<unsigned char>(e[0])) << 8) | static_cast<unsigned char>(e[1]);
  } else if (n == 127) {
    const std::string e = c.recvExactly(8);
    if (e.size() < 8) return f;
    n = 0;
    for (char b : e) n = (n << 8) | static_cast<unsigned char>(b);
  }
  f.payload = c.recvExactly(static_cast<size_t>(n));
  if (f.payload.size() != n) return f;
  f.opcode = op;
  return f;
}

/// The next text or close frame, or opcode -1. Map frames are skipped: binary messages and
/// their continuation frames (Beast fragments large messages; the short replies never are).
Frame nextTextOrClose(Conn& c) {
  for (int i = 0; i < 100000; ++i) {
    Frame f = readFrame(c);
    if (f.opcode != 2 && f.opcode != 0) return f;
  }
  return {};
}

bool openSocket(Conn& c, const Server& s) {
  if (!c.ok()) return false;
  c.send(upgradeRequest(s.hostHeader(), "http://" + s.hostHeader()));
  return status(c.recvHead()).find(" 101") != std::string::npos;
}

}  // namespace

TEST(ServeHostile, RequestsResolveInsideTheRootOr404) {
  Server s("paths");
  ASSERT_GT(s.port(), 0) << s.output();
  const std::string host = s.hostHeader();
  EXPECT_NE(status(get(s.port(), "/index.html", host)).find(" 200"), std::string::npos);
  EXPECT_NE(get(s.port(), "/", host).find("live view"), std::string::npos);
  const std::string secret = (s.dir() / "secret.txt").string();
  for (const std::string target : std::vector<std::string>{"//etc/passwd", "//proc/self/environ", "//" + secret, "/../secret.txt",
                                   "/./../secret.txt", "/link.txt", "/%2e%2e/secret.txt", "/web/../../secret.txt",
                                   "/index.html/../../secret.txt"}) {
    const std::string r = get(s.port(), target, host);
    EXPECT_NE(status(r).find(" 404"), std::string::npos) << target << " -> " << status(r);
    EXPECT_EQ(r.find(kSecret), std::string::npos) << target;
    EXPECT_EQ(r.find("root:"), std::string::npos) << target;
    // An error page names no path of the machine.
    EXPECT_EQ(r.find(s.root().string()), std::string::npos) << target;
  }
  EXPECT_TRUE(s.alive());
}

TEST(ServeHostile, EveryBadCommandIsAnsweredWithAnErrorAndTheServerStaysUp) {
  Server s("commands");
  ASSERT_GT(s.port(), 0) << s.output();
  Conn c(s.port());
  ASSERT_TRUE(openSocket(c, s));
  for (const std::string cmd : std::vector<std::string>{R"({"cmd": 5})", R"({"cmd": null})", R"([1, 2])", R"("play")", "not json",
                                R"({"cmd": "layer", "name": 7})", R"({"cmd": "layer", "name": "no_such_layer"})",
                                R"({"cmd": "fly"})", R"({"cmd": "play", "extra": 1})", R"({})"}) {
    ASSERT_TRUE(c.send(frame(cmd)));
    const Frame f = nextTextOrClose(c);
    EXPECT_EQ(f.opcode, 1) << cmd;
    EXPECT_NE(f.payload.find("\"error\""), std::string::npos) << cmd << " -> " << f.payload;
  }
  // A binary message is not a command either.
  ASSERT_TRUE(c.send(frame("\x01\x02", 2)));
  EXPECT_NE(nextTextOrClose(c).payload.find("\"error\""), std::string::npos);
  // A good one still works on the same socket, and the server still serves pages.
  ASSERT_TRUE(c.send(frame(R"({"cmd": "pause"})")));
  ASSERT_TRUE(c.send(frame(R"({"cmd": "layer", "name": "elevation"})")));
  std::this_thread::sleep_for(std::chrono::milliseconds(200));
  EXPECT_TRUE(s.alive()) << s.output();
  EXPECT_NE(status(get(s.port(), "/index.html", s.hostHeader())).find(" 200"), std::string::npos);
}

TEST(ServeHostile, ForeignOriginOrHostIsRefused) {
  Server s("origin");
  ASSERT_GT(s.port(), 0) << s.output();
  const std::string host = s.hostHeader(), port = std::to_string(s.port());
  // A page of another site driving the socket: its Origin is its own.
  for (const std::string origin : std::vector<std::string>{"http://evil.example", "null", "http://127.0.0.1:1", "https://" + host}) {
    Conn c(s.port());
    c.send(upgradeRequest(host, origin));
    EXPECT_NE(status(c.recvHead()).find(" 403"), std::string::npos) << origin;
  }
  // DNS rebinding: the browser thinks it talks to evil.example, so Host says so.
  for (const std::string bad_host : std::vector<std::string>{"evil.example:" + port, "rebind.evil.example:" + port, "127.0.0.1:1", ""}) {
    EXPECT_NE(status(get(s.port(), "/index.html", bad_host)).find(" 403"), std::string::npos) << bad_host;
    Conn c(s.port());
    c.send(upgradeRequest(bad_host, "http://" + bad_host));
    EXPECT_NE(status(c.recvHead()).find(" 403"), std::string::npos) << bad_host;
  }
  // The page's own origin, by address or by name, and clients that send no Origin (curl).
  for (const std::string ok : std::vector<std::string>{host, "localhost:" + port}) {
    Conn c(s.port());
    c.send(upgradeRequest(ok, "http://" + ok));
    EXPECT_NE(status(c.recvHead()).find(" 101"), std::string::npos) << ok;
  }
  Conn c(s.port());
  c.send(upgradeRequest(host, ""));
  EXPECT_NE(status(c.recvHead()).find(" 101"), std::string::npos);
  EXPECT_TRUE(s.alive());
}

TEST(ServeHostile, ConnectionsAndMessageSizeAreCapped) {
  Server s("caps", {"--max-connections", "3", "--max-message-bytes", "1024"});
  ASSERT_GT(s.port(), 0) << s.output();
  {
    std::vector<std::unique_ptr<Conn>> held;
    for (int i = 0; i < 3; ++i) {
      held.push_back(std::make_unique<Conn>(s.port()));
      ASSERT_TRUE(openSocket(*held.back(), s)) << i;
    }
    // The fourth is turned away (503, or closed) while three are open.
    const std::string r = get(s.port(), "/index.html", s.hostHeader());
    EXPECT_EQ(status(r).find(" 200"), std::string::npos) << status(r);
    // A message over the limit closes that socket (1009), the others stay.
    ASSERT_TRUE(held[0]->send(frame(std::string(2000, ' ') + R"({"cmd": "pause"})")));
    const Frame f = nextTextOrClose(*held[0]);
    EXPECT_TRUE(f.opcode == 8 || f.opcode == -1) << f.opcode;
    if (f.opcode == 8 && f.payload.size() >= 2)
      EXPECT_EQ((static_cast<unsigned char>(f.payload[0]) << 8) | static_cast<unsigned char>(f.payload[1]), 1009);
    ASSERT_TRUE(held[1]->send(frame(R"({"cmd": 5})")));
    EXPECT_EQ(nextTextOrClose(*held[1]).opcode, 1);
  }
  // Once they are gone, connections are taken again.
  bool served = false;
  for (int i = 0; i < 50 && !served; ++i) {
    served = status(get(s.port(), "/index.html", s.hostHeader())).find(" 200") != std::string::npos;
    if (!served) std::this_thread::sleep_for(std::chrono::milliseconds(100));
  }
  EXPECT_TRUE(served);
  EXPECT_TRUE(s.alive());
}

TEST(ServeHostile, ListensOnLoopbackUnlessAPublicAddressIsAllowedExplicitly) {
  Server s("bind");
  ASSERT_GT(s.port(), 0) << s.output();
  EXPECT_EQ(s.host(), "127.0.0.1");
  const Result r = sh("serve " + kPipeline + " --port 0 --host 0.0.0.0 --exit-after 0");
  EXPECT_EQ(r.code, 2) << r.out;
  EXPECT_NE(r.out.find("--allow-remote"), std::string::npos) << r.out;
}

// ---- The Foxglove endpoint (ws://HOST:PORT/, subprotocol foxglove.websocket.v1) gets the same guards.
namespace {

std::string foxgloveUpgrade(const std::string& host, const std::string& origin, const std::string& target = "/") {
  std::string r = "GET " + target + " HTTP/1.1\r\nHost: " + host +
                  "\r\nUpgrade: websocket\r\nConnection: Upgrade\r\nSec-WebSocket-Key: dGhlIHNhbXBsZSBub25jZQ==\r\n"
                  "Sec-WebSocket-Version: 13\r\nSec-WebSocket-Protocol: foxglove.websocket.v1\r\n";
  if (!origin.empty()) r += "Origin: " + origin + "\r\n";
  return r + "\r\n";
}

/// Opens the Foxglove endpoint and reads its serverInfo and advertise.
bool openFoxglove(Conn& c, const Server& s) {
  if (!c.ok()) return false;
  c.send(foxgloveUpgrade(s.hostHeader(), ""));
  const std::string head = c.recvHead();
  if (head.find(" 101") == std::string::npos || head.find("foxglove.websocket.v1") == std::string::npos) return false;
  return nextTextOrClose(c).payload.find("\"serverInfo\"") != std::string::npos &&
         nextTextOrClose(c).payload.find("\"advertise\"") != std::string::npos;
}

}  // namespace

TEST(ServeHostile, FoxgloveEndpointRefusesForeignOriginOrHost) {
  Server s("fox_origin", {"--foxglove-origin", "https://app.foxglove.dev"});
  ASSERT_GT(s.port(), 0) << s.output();
  const std::string host = s.hostHeader(), port = std::to_string(s.port());
  for (const std::string& origin : std::vector<std::string>{"http://evil.example", "null", "http://127.0.0.1:1", "https://" + host,
                                                           "https://app.foxglove.dev.evil.example"}) {
    Conn c(s.port());
    c.send(foxgloveUpgrade(host, origin));
    EXPECT_NE(status(c.recvHead()).find(" 403"), std::string::npos) << origin;
  }
  for (const std::string& bad_host : std::vector<std::string>{"evil.example:" + port, "127.0.0.1:1", ""}) {
    Conn c(s.port());
    c.send(foxgloveUpgrade(bad_host, ""));
    EXPECT_NE(status(c.recvHead()).find(" 403"), std::string::npos) << bad_host;
  }
  // The listed Origin (Foxglove's web app) opens the Foxglove endpoint, not the page's socket.
  for (const std::string& ok : std::vector<std::string>{"https://app.foxglove.dev", "http://" + host, ""}) {
    Conn c(s.port());
    c.send(foxgloveUpgrade(host, ok));
    EXPECT_NE(status(c.recvHead()).find(" 101"), std::string::npos) << ok;
  }
  Conn live(s.port());
  live.send(upgradeRequest(host, "https://app.foxglove.dev"));
  EXPECT_NE(status(live.recvHead()).find(" 403"), std::string::npos);
  EXPECT_TRUE(s.alive());
}

TEST(ServeHostile, FoxgloveBadRequestsAreAnsweredWithAnErrorStatusAndTheServerStaysUp) {
  Server s("fox_requests");
  ASSERT_GT(s.port(), 0) << s.output();
  Conn c(s.port());
  ASSERT_TRUE(openFoxglove(c, s));
  for (const std::string& req : std::vector<std::string>{
           "not json", R"([1, 2])", R"({"op": 5})", R"({})", R"({"op": "fly"})", R"({"op": "subscribe"})",
           R"({"op": "subscribe", "subscriptions": 3})", R"({"op": "subscribe", "subscriptions": [7]})",
           R"({"op": "subscribe", "subscriptions": [{"id": -1, "channelId": 0}]})",
           R"({"op": "subscribe", "subscriptions": [{"id": 1.5, "channelId": 0}]})",
           R"({"op": "subscribe", "subscriptions": [{"id": 4294967296, "channelId": 0}]})",
           R"({"op": "subscribe", "subscriptions": [{"id": 1, "channelId": 99}]})",
           R"({"op": "unsubscribe", "subscriptionIds": [12]})", R"({"op": "unsubscribe", "subscriptionIds": ["a"]})",
           R"({"op": "advertise", "channels": []})", R"({"op": "getParameters", "parameterNames": []})",
           R"({"op": "fetchAsset", "uri": "file:///etc/passwd", "requestId": 1})"}) {
    ASSERT_TRUE(c.send(frame(req))) << req;
    const Frame f = nextTextOrClose(c);
    EXPECT_EQ(f.opcode, 1) << req;
    EXPECT_NE(f.payload.find("\"op\":\"status\""), std::string::npos) << req << " -> " << f.payload;
    EXPECT_NE(f.payload.find("\"level\":2"), std::string::npos) << req << " -> " << f.payload;
  }
  // A binary message (client publishing, service calls) is refused the same way.
  ASSERT_TRUE(c.send(frame(std::string("\x01\x00\x00\x00\x00", 5), 2)));
  EXPECT_NE(nextTextOrClose(c).payload.find("\"level\":2"), std::string::npos);
  // Twice the same id, or the same channel twice: the second is refused.
  ASSERT_TRUE(c.send(frame(R"({"op": "subscribe", "subscriptions": [{"id": 7, "channelId": 0}, {"id": 7, "channelId": 1}]})")));
  EXPECT_NE(nextTextOrClose(c).payload.find("in use"), std::string::npos);
  // The good subscription of that request stands: its Grid arrives (opcode 1, subscription 7).
  Frame data;
  for (int i = 0; i < 1000 && data.opcode != 2; ++i) data = readFrame(c);
  ASSERT_EQ(data.opcode, 2);
  ASSERT_GE(data.payload.size(), 13u);
  EXPECT_EQ(data.payload[0], 0x01);
  EXPECT_EQ(data.payload.substr(1, 4), std::string("\x07\x00\x00\x00", 4));
  EXPECT_NE(data.payload.find("\"column_count\""), std::string::npos);
  EXPECT_TRUE(s.alive()) << s.output();
  EXPECT_NE(status(get(s.port(), "/index.html", s.hostHeader())).find(" 200"), std::string::npos);
}

TEST(ServeHostile, FoxgloveConnectionsAndMessageSizeAreCapped) {
  Server s("fox_caps", {"--max-connections", "3", "--max-message-bytes", "1024"});
  ASSERT_GT(s.port(), 0) << s.output();
  std::vector<std::unique_ptr<Conn>> held;
  for (int i = 0; i < 2; ++i) {
    held.push_back(std::make_unique<Conn>(s.port()));
    ASSERT_TRUE(openFoxglove(*held.back(), s)) << i;
  }
  held.push_back(std::make_unique<Conn>(s.port()));
  ASSERT_TRUE(openSocket(*held.back(), s));
  // Both endpoints count against one cap: a fourth Foxglove client is turned away.
  Conn fourth(s.port());
  fourth.send(foxgloveUpgrade(s.hostHeader(), ""));
  EXPECT_EQ(status(fourth.recvHead()).find(" 101"), std::string::npos);
  // A request over the limit closes that socket (1009); the other Foxglove client is still served.
  ASSERT_TRUE(held[0]->send(frame(R"({"op": "subscribe", "subscriptions": [)" + std::string(2000, ' ') + "]}")));
  const Frame f = nextTextOrClose(*held[0]);
  EXPECT_TRUE(f.opcode == 8 || f.opcode == -1) << f.opcode;
  if (f.opcode == 8 && f.payload.size() >= 2) {
    EXPECT_EQ((static_cast<unsigned char>(f.payload[0]) << 8) | static_cast<unsigned char>(f.payload[1]), 1009);
  }
  ASSERT_TRUE(held[1]->send(frame(R"({"op": 5})")));
  EXPECT_NE(nextTextOrClose(*held[1]).payload.find("\"level\":2"), std::string::npos);
  EXPECT_TRUE(s.alive());
}

TEST(ServeHostile, FoxgloveLayersAreCheckedBeforeServing) {
  Result r = sh("serve " + kPipeline + " --port 0 --exit-after 0 --foxglove-layers elevation,elevaton");
  EXPECT_NE(r.code, 0) << r.out;
  EXPECT_NE(r.out.find("no layer 'elevaton'"), std::string::npos) << r.out;
  EXPECT_NE(r.out.find("did you mean 'elevation'"), std::string::npos) << r.out;
  EXPECT_EQ(r.out.find("serving"), std::string::npos) << r.out;
  r = sh("serve " + kPipeline + " --port 0 --exit-after 0 --foxglove-layers variance,variance");
  EXPECT_NE(r.code, 0) << r.out;
  EXPECT_NE(r.out.find("'variance' is given twice"), std::string::npos) << r.out;
}

TEST(ServeHostile, FoxgloveFrameMustBeAPrintableName) {
  for (const std::string& bad : std::vector<std::string>{"''", "'a b'", "\"$(printf 'map\\tx')\"", std::string(300, 'm')}) {
    const Result r = sh("serve " + kPipeline + " --port 0 --exit-after 0 --foxglove-frame " + bad);
    EXPECT_EQ(r.code, 2) << bad << ": " << r.out;
    EXPECT_NE(r.out.find("--foxglove-frame"), std::string::npos) << bad << ": " << r.out;
  }
}

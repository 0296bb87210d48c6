// `terramap serve PIPELINE.yaml`: runs a pipeline and shows it live in the browser (three.js
// surface coloured by any layer, the machine and its blade, play/pause, layer picker).
// The pipeline runs on its own thread; every frame period it takes a snapshot (copy-on-write,
// cheap), samples the elevation and the chosen layer onto at most --max-grid cells a side and
// publishes one binary frame (format in web/app.js) to every connected page. Foxglove clients
// get the map as foxglove.Grid (the chosen layers, full resolution up to --foxglove-max-grid)
// and the latest cloud as foxglove.PointCloud, at the same pace, built only while subscribed.
#include "command.hpp"
#include "foxglove_ws.hpp"
#include "live_server.hpp"

#include <terramap/core/error.hpp>
#include <terramap/core/text.hpp>
#include <terramap/io/geotiff.hpp>
#include <terramap/io/render.hpp>
#include <terramap/pipeline/engine.hpp>
#include <terramap/pipeline/pipeline_spec.hpp>
#include <terramap/pipeline/plugin_loader.hpp>
#include <terramap/pipeline/source.hpp>

#define BOOST_DLL_USE_STD_FS
#include <boost/asio/ip/address.hpp>
#include <boost/dll/runtime_symbol_info.hpp>
#include <nlohmann/json.hpp>

#include <algorithm>
#include <atomic>
#include <chrono>
#include <cmath>
#include <condition_variable>
#include <csignal>
#include <cstdio>
#include <cstring>
#include <mutex>
#include <thread>

namespace terramap::cli {
namespace {

namespace fs = std::filesystem;

struct ServeArgs {
  std::string file;
  std::vector<std::string> set;  ///< --set STAGE.KEY=VALUE
  int port = 8765;
  double speed = 1.0;
  double frame_period_s = 0.1;
  int max_grid = 256;
  int threads = 0;
  double exit_after_s = -1;
  bool wait_for_viewer = false;
  std::string web_root;
  std::string host = "127.0.0.1";
  bool allow_remote = false;
  int max_connections = 32;
  int max_message_bytes = 4096;
  std::vector<std::string> foxglove_layers{"elevation"};
  int foxglove_max_grid = 1024;
  std::string foxglove_frame = "map";
  std::vector<std::string> foxglove_origins;
};

/// The Foxglove endpoint's channels, in the order of their ids.
enum FoxgloveChannelId : std::uint32_t { kGridChannel = 0, kCloudChannel = 1 };

std::atomic<bool> g_interrupted{false};
void onSignal(int) { g_interrupted = true; }

/// Where the page lives: --web-root, else <bin>/../share/terramap/web (build and install trees).
fs::path webRoot(const std::string& given) {
  if (!given.empty()) return given;
  return (fs::path(boost::dll::program_location().parent_path().string()) / ".." / "share" / "terramap" / "web")
      .lexically_normal();
}

/// What a client sent, as an error message may quote it: short, whatever its length.
std::string clip(const std::string& s) { return s.size() <= 64 ? s : s.substr(0, 64) + "..."; }

std::vector<double> columnMajor(const Eigen::Isometry3d& T) {
  const Eigen::Matrix4d m = T.matrix();
  return std::vector<double>(m.data(), m.data() + 16);
}

/// The pipeline side: plays the source, answers the page's commands, builds frames.
class Player {
 public:
  Player(const ServeArgs& a, LiveServer& server) : a_(a), server_(server) {
    PipelineSpec spec = parsePipelineFile(a.file);
    applyParamOverrides(spec, a.set);
    if (a.threads > 0) spec.threads = a.threads;
    engine_ = Engine::fromSpec(spec, PluginRegistry::forPipeline(spec.plugin_paths, spec.plugin_paths_where));
    source_ = makeSource(spec);
    if (!engine_->map().hasLayer("elevation"))
      throw ConfigError(a.file + ": the live view shows the layer 'elevation', which no stage creates");
    layer_names_ = engine_->map().layerNames();  // fixed from here on: commands are checked against it
    for (std::size_t k = 0; k < a.foxglove_layers.size(); ++k) {
      const std::string& l = a.foxglove_layers[k];
      if (std::find(a.foxglove_layers.begin(), a.foxglove_layers.begin() + k, l) != a.foxglove_layers.begin() + k)
        throw ConfigError("--foxglove-layers: '" + l + "' is given twice (a Grid's field names are unique)");
      if (std::find(layer_names_.begin(), layer_names_.end(), l) == layer_names_.end())
        throw ConfigError("--foxglove-layers: no layer '" + l + "' in " + a.file + didYouMean(l, layer_names_) +
                          "; layers: [" + joinStrings(layer_names_) + "]");
    }
    colour_layer_ = "elevation";
    playing_ = !a.wait_for_viewer;
  }

  /// A page connected: the first one starts a run that waits for a viewer.
  void viewerConnected() {
    std::lock_guard<std::mutex> lock(mu_);
    if (a_.wait_for_viewer && !started_) playing_ = true;
    started_ = true;
    republish_ = true;
    cv_.notify_all();
  }

  /// One message of a page: {"cmd": "play"}, {"cmd": "pause"} or {"cmd": "layer", "name": L}.
  /// Anything else changes nothing and is answered with its error (returned; "" = accepted).
  std::string command(const std::string& text) {
    const nlohmann::json j = nlohmann::json::parse(text, nullptr, false);
    if (j.is_discarded()) return LiveServer::errorMessage("not JSON: a command is {\"cmd\": \"play\" | \"pause\" | \"layer\"}");
    if (!j.is_object()) return LiveServer::errorMessage("a command is a JSON object, {\"cmd\": ...}");
    const auto it = j.find("cmd");
    if (it == j.end() || !it->is_string())
      return LiveServer::errorMessage("'cmd' must be the string play, pause or layer");
    const std::string cmd = it->get<std::string>();
    if (cmd != "play" && cmd != "pause" && cmd != "layer")
      return LiveServer::errorMessage("unknown cmd '" + clip(cmd) + "'" + didYouMean(cmd, {"play", "pause", "layer"}) +
                                      " (play, pause, layer)");
    for (const auto& [key, value] : j.items())
      if (key != "cmd" && !(cmd == "layer" && key == "name"))
        return LiveServer::errorMessage("cmd '" + cmd + "' takes no key '" + clip(key) + "'");
    std::string layer;
    if (cmd == "layer") {
      const auto name = j.find("name");
      if (name == j.end() || !name->is_string()) return LiveServer::errorMessage("cmd 'layer' needs \"name\": a layer name");
      layer = name->get<std::string>();
      if (std::find(layer_names_.begin(), layer_names_.end(), layer) == layer_names_.end())
        return LiveServer::errorMessage("no layer '" + clip(layer) + "'" + didYouMean(layer, layer_names_) + "; layers: [" +
                                        joinStrings(layer_names_) + "]");
    }
    std::lock_guard<std::mutex> lock(mu_);
    if (cmd == "pause") playing_ = false;
    if (cmd == "play") playing_ = true;
    if (cmd == "layer") requested_layer_ = layer;
    republish_ = true;
    cv_.notify_all();
    return "";
  }

  /// A Foxglove client subscribed: it gets the current map (and cloud) at once.
  void republish() {
    std::lock_guard<std::mutex> lock(mu_);
    republish_ = true;
    resend_cloud_ = true;
    cv_.notify_all();
  }

  void stop() {
    std::lock_guard<std::mutex> lock(mu_);
    stop_ = true;
    cv_.notify_all();
  }

  /// Runs until the source ends (then keeps answering commands) or stop().
  void run() {
    const auto wall0 = std::chrono::steady_clock::now();
    auto last_frame = wall0 - std::chrono::hours(1);
    double stamp0 = NAN;
    Event e;
    while (true) {
      {
        std::unique_lock<std::mutex> lock(mu_);
        cv_.wait_for(lock, std::chrono::milliseconds(done_ || !playing_ ? 50 : 0),
                     [&] { return stop_ || republish_ || (playing_ && !done_); });
        if (stop_) return;
        if (republish_) {
          republish_ = false;
          if (!requested_layer_.empty() && engine_->map().hasLayer(requested_layer_)) colour_layer_ = requested_layer_;
          requested_layer_.clear();
          lock.unlock();
          publish();
          continue;
        }
        if (!playing_ || done_) continue;
      }
      if (!source_->next(e)) {
        engine_->finish();
        {
          std::lock_guard<std::mutex> lock(mu_);
          done_ = true;
        }
        publish();
        server_.foxgloveStatus(0, "source finished after " + std::to_string(events_) + " events", "terramap.source");
        std::printf("source finished after %ld events\n", events_);
        std::fflush(stdout);
        continue;
      }
      const double stamp = stampOf(e);
      if (std::isnan(stamp0)) stamp0 = stamp;
      remember(e);
      engine_->push(e);
      ++events_;
      if (auto* cloud = std::get_if<PointCloud>(&e)) {
        // The engine is done with it: kept (moved, not copied) for the Foxglove cloud channel.
        latest_cloud_ = std::make_shared<const PointCloud>(std::move(*cloud));
        ++cloud_seq_;
      }
      stamp_ = stamp;
      if (a_.speed > 0) {  // keep the source's pace, scaled
        const auto due = wall0 + std::chrono::duration<double>((stamp - stamp0) / a_.speed);
        std::this_thread::sleep_until(std::chrono::time_point_cast<std::chrono::steady_clock::duration>(due));
      }
      const auto now = std::chrono::steady_clock::now();
      if (now - last_frame >= std::chrono::duration<double>(a_.frame_period_s)) {
        last_frame = now;
        publish();
      }
    }
  }

  bool done() {
    std::lock_guard<std::mutex> lock(mu_);
    return done_;
  }

 private:
  void remember(const Event& e) {
    if (const auto* p = std::get_if<Pose>(&e)) T_base_ = p->T_map_base;
    if (const auto* o = std::get_if<Observation>(&e)) T_base_ = o->T_map_base;
    if (const auto* b = std::get_if<BladePose>(&e)) {
      T_blade_ = b->T_map_blade;
      blade_ = b->geometry;
    }
  }

  /// One frame: header JSON, then the elevation and the colour layer, north-up, sampled with a
  /// stride so that neither side exceeds max_grid.
  void publish() {
    const std::shared_ptr<const LayeredMap> snap = engine_->snapshot();
    const Geometry& g = snap->geometry();
    const LayerId hid = snap->layerId("elevation"), cid = snap->layerId(colour_layer_);
    // North-up raster of the map: map_rows = the map's columns (y), map_cols = its rows (x).
    const int map_rows = g.size().y(), map_cols = g.size().x();
    const int stride = std::max(1, static_cast<int>(std::ceil(static_cast<double>(std::max(map_rows, map_cols)) / a_.max_grid)));
    const int rows = (map_rows + stride - 1) / stride, cols = (map_cols + stride - 1) / stride;
    io::RenderOptions ro;
    const bool diverging = colour_layer_.find("error") != std::string::npos;
    if (diverging) ro.colormap = "rdbu";
    const io::ValueRange range = io::renderRange(*snap, cid, ro);
    // Sample positions: raster pixel (r, c) is the cell at x = xmin + (c + 0.5) res,
    // y = ymax - (r + 0.5) res; the extent spans the sampled cell centres.
    const double res = g.resolution();
    const double xmin = g.center().x() - 0.5 * g.size().x() * res, ymax = g.center().y() + 0.5 * g.size().y() * res;
    nlohmann::json j = {{"seq", ++seq_},
                        {"stamp", std::isfinite(stamp_) ? stamp_ : 0.0},
                        {"events", events_},
                        {"rows", rows},
                        {"cols", cols},
                        {"stride", stride},
                        {"map_rows", map_rows},
                        {"map_cols", map_cols},
                        {"resolution", res},
                        {"extent", {xmin + 0.5 * res, xmin + (0.5 + (cols - 1) * stride) * res,
                                    ymax - (0.5 + (rows - 1) * stride) * res, ymax - 0.5 * res}},
                        {"map_extent", {xmin, xmin + g.size().x() * res, ymax - g.size().y() * res, ymax}},
                        {"layers", snap->layerNames()},
                        {"color_layer", colour_layer_},
                        {"color_unit", snap->layerInfo(cid).unit},
                        {"color_range", {range.min, range.max}},
                        {"diverging", diverging},
                        {"blade_width_m", blade_.width_m},
                        {"blade_height_m", blade_.height_m}};
    {
      std::lock_guard<std::mutex> lock(mu_);
      j["playing"] = playing_;
      j["done"] = done_;
    }
    if (T_base_) j["T_map_base"] = columnMajor(*T_base_);
    if (T_blade_) j["T_map_blade"] = columnMajor(*T_blade_);
    const std::string head = j.dump();
    const std::size_t pad = (4 - (4 + head.size()) % 4) % 4, cells = static_cast<std::size_t>(rows) * cols;
    std::string frame(4 + head.size() + pad + 8 * cells, '\0');
    const std::uint32_t n = static_cast<std::uint32_t>(head.size());
    std::memcpy(&frame[0], &n, 4);  // little-endian on every machine terramap builds for
    std::memcpy(&frame[4], head.data(), head.size());
    float* out = reinterpret_cast<float*>(&frame[4 + head.size() + pad]);
    for (int r = 0; r < rows; ++r)
      for (int k = 0; k < cols; ++k) {
        // Only the sampled cells are read: no whole-layer copy per frame.
        const Index cell = io::logicalIndexOfPixel(g, r * stride, k * stride);
        out[static_cast<std::size_t>(r) * cols + k] = snap->at(hid, cell);
        out[cells + static_cast<std::size_t>(r) * cols + k] = snap->at(cid, cell);
      }
    server_.publish(std::move(frame));
    publishFoxglove(*snap);
  }

  /// The map and the newest cloud to Foxglove clients, each built only if someone subscribed.
  void publishFoxglove(const LayeredMap& snap) {
    const double stamp = std::isfinite(stamp_) ? stamp_ : 0.0;
    if (server_.foxgloveSubscribed(kGridChannel)) {
      const Geometry& g = snap.geometry();
      const int side = std::max(g.size().x(), g.size().y());
      const int stride = std::max(1, (side + a_.foxglove_max_grid - 1) / a_.foxglove_max_grid);
      server_.publishFoxglove(kGridChannel, foxglove::stampNs(stamp),
                              foxglove::gridMessage(snap, a_.foxglove_layers, stride, stamp, a_.foxglove_frame));
    }
    bool resend = false;
    {
      std::lock_guard<std::mutex> lock(mu_);
      std::swap(resend, resend_cloud_);
    }
    if (latest_cloud_ && (resend || cloud_seq_ != sent_cloud_seq_) && server_.foxgloveSubscribed(kCloudChannel)) {
      sent_cloud_seq_ = cloud_seq_;
      server_.publishFoxglove(kCloudChannel, foxglove::stampNs(latest_cloud_->stamp),
                              foxglove::pointCloudMessage(*latest_cloud_, a_.foxglove_frame));
    }
  }

  const ServeArgs& a_;
  LiveServer& server_;
  std::unique_ptr<Engine> engine_;
  std::unique_ptr<Source> source_;
  std::mutex mu_;
  std::condition_variable cv_;
  bool playing_ = true, done_ = false, stop_ = false, republish_ = false, started_ = false, resend_cloud_ = false;
  std::shared_ptr<const PointCloud> latest_cloud_;  // pipeline thread only
  long cloud_seq_ = 0, sent_cloud_seq_ = 0;
  std::string colour_layer_, requested_layer_;
  std::vector<std::string> layer_names_;
  long events_ = 0, seq_ = 0;
  double stamp_ = NAN;
  std::optional<Eigen::Isometry3d> T_base_, T_blade_;
  BladeGeometry blade_;
};

Registrar reg{Command{"serve", [](CLI::App& app, std::function<int()>& run) {
  auto a = std::make_shared<ServeArgs>();
  auto* sub = app.add_subcommand("serve",
      "Run a pipeline and watch it live in a browser: serves http://127.0.0.1:PORT/ (a three.js\n"
      "view of the elevation coloured by any layer, the machine and blade, play/pause, layer\n"
      "picker), fed over a WebSocket. Everything the page needs is served from the build;\n"
      "nothing is fetched from the internet. Ctrl-C stops it. Only this machine can connect\n"
      "unless --host names another address and --allow-remote is given; requests whose Host or\n"
      "Origin is not this server are refused (docs/reliability.md, \"The live view\").\n"
      "Foxglove: connect to ws://127.0.0.1:PORT for the map (foxglove.Grid, /terramap/map) and the\n"
      "latest cloud (foxglove.PointCloud, /terramap/cloud); docs/foxglove.md.");
  sub->add_option("pipeline", a->file, "Pipeline YAML file")->required()->check(CLI::ExistingFile);
  sub->add_option("--port,-p", a->port, "Port on 127.0.0.1 (0 = any free port)")->capture_default_str()->check(CLI::Range(0, 65535));
  sub->add_option("--speed", a->speed, "Playback speed x real time of the source's stamps (0 = as fast as possible)")
      ->capture_default_str()->check(CLI::NonNegativeNumber);
  sub->add_option("--frame-period", a->frame_period_s, "Seconds of wall time between frames")->capture_default_str()
      ->check(CLI::Range(0.01, 10.0));
  sub->add_option("--max-grid", a->max_grid, "Largest grid side sent to the page (cells; the map is sampled)")
      ->capture_default_str()->check(CLI::Range(16, 2048));
  sub->add_option("--threads,-j", a->threads, "Worker threads (overrides `threads`)")->check(CLI::Range(1, 256));
  sub->add_option("--set", a->set, "Stage parameter for this run, STAGE.KEY=VALUE (repeatable)");
  sub->add_option("--exit-after", a->exit_after_s, "Stop this many seconds after the source ends (default: never)");
  sub->add_flag("--wait-for-viewer", a->wait_for_viewer, "Start playing when the first page connects");
  sub->add_option("--web-root", a->web_root, "Folder of the page (default: the installed one)");
  sub->add_option("--host", a->host, "IP address to listen on (0.0.0.0: every interface; needs --allow-remote)")
      ->capture_default_str();
  sub->add_flag("--allow-remote", a->allow_remote,
                "Allow --host to be an address other machines can reach (they can then watch and drive the run)");
  sub->add_option("--max-connections", a->max_connections, "Open connections served at once (more are answered 503)")
      ->capture_default_str()->check(CLI::Range(1, 10000));
  sub->add_option("--max-message-bytes", a->max_message_bytes, "Largest WebSocket message a page may send (bytes)")
      ->capture_default_str()->check(CLI::Range(64, 1 << 20));
  sub->add_option("--foxglove-layers", a->foxglove_layers,
                  "Layers published to Foxglove clients as the fields of the foxglove.Grid on /terramap/map "
                  "(comma-separated or repeated)")
      ->delimiter(',')->capture_default_str();
  sub->add_option("--foxglove-max-grid", a->foxglove_max_grid,
                  "Largest grid side sent to Foxglove clients (cells; larger maps are sampled every k-th cell)")
      ->capture_default_str()->check(CLI::Range(16, 16384));
  sub->add_option("--foxglove-frame", a->foxglove_frame, "frame_id of the Foxglove messages (the map frame)")
      ->capture_default_str()
      ->check([](const std::string& f) {
        const bool printable = std::all_of(f.begin(), f.end(), [](char c) { return c > 0x20 && c < 0x7f; });
        return !f.empty() && f.size() <= 256 && printable ? std::string() : std::string("a frame id is 1 to 256 printable characters, no spaces");
      });
  sub->add_option("--foxglove-origin", a->foxglove_origins,
                  "An Origin besides this server's that may open the Foxglove endpoint, e.g. https://app.foxglove.dev "
                  "(repeatable; clients that send no Origin need none)");
  sub->callback([&run, a] {
    run = [a]() -> int {
      {
        boost::system::error_code ec;
        const auto addr = boost::asio::ip::make_address(a->host, ec);
        if (ec) {
          std::cerr << "terramap serve: --host '" << a->host << "' is not an IP address\n";
          return kUsage;
        }
        if (!addr.is_loopback() && !a->allow_remote) {
          std::cerr << "terramap serve: --host " << a->host
                    << " listens beyond this machine: whoever reaches it can watch and drive the run. Pass "
                       "--allow-remote if that is meant.\n";
          return kUsage;
        }
      }
      const fs::path root = webRoot(a->web_root);
      if (!fs::is_regular_file(root / "index.html") || !fs::is_regular_file(root / "three.module.js"))
        throw OutputError("the live view's page is not at " + root.string() +
                          " (built with TERRAMAP_WITH_WEB, or give --web-root)");
      LiveServerOptions so;
      so.address = a->host;
      so.port = static_cast<std::uint16_t>(a->port);
      so.web_root = root;
      so.max_connections = a->max_connections;
      so.max_message_bytes = static_cast<std::size_t>(a->max_message_bytes);
      so.foxglove_origins = a->foxglove_origins;
      LiveServer server(so);
      Player player(*a, server);
      server.foxgloveChannels({{"/terramap/map", "foxglove.Grid", foxglove::gridSchema()},
                               {"/terramap/cloud", "foxglove.PointCloud", foxglove::pointCloudSchema()}});
      server.onCommand([&player](const std::string& c) { return player.command(c); });
      server.onConnect([&player] { player.viewerConnected(); });
      server.onFoxgloveSubscribe([&player](std::uint32_t) { player.republish(); });
      std::signal(SIGINT, onSignal);
      std::signal(SIGTERM, onSignal);
      std::thread io([&server] { server.run(); });
      std::printf("serving http://%s:%u/ (Ctrl-C to stop; Foxglove: ws://%s:%u)\n", a->host.c_str(),
                  static_cast<unsigned>(server.port()), a->host.c_str(), static_cast<unsigned>(server.port()));
      std::fflush(stdout);
      std::exception_ptr failure;
      std::thread pipeline([&] {
        try {
          player.run();
        } catch (...) {
          failure = std::current_exception();
          g_interrupted = true;
        }
      });
      auto done_since = std::chrono::steady_clock::time_point::max();
      while (!g_interrupted) {
        std::this_thread::sleep_for(std::chrono::milliseconds(50));
        if (a->exit_after_s >= 0 && player.done()) {
          const auto now = std::chrono::steady_clock::now();
          if (done_since == std::chrono::steady_clock::time_point::max()) done_since = now;
          if (now - done_since >= std::chrono::duration<double>(a->exit_after_s)) break;
        }
      }
      player.stop();
      pipeline.join();
      server.stop();
      io.join();
      if (failure) std::rethrow_exception(failure);
      return kOk;
    };
  });
}}};

}  // namespace
}  // namespace terramap::cli

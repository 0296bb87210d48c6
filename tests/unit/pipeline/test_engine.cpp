#include <terramap/core/error.hpp>
#include <terramap/pipeline/engine.hpp>
#include <terramap/pipeline/report.hpp>
#include <terramap/pipeline/run.hpp>
#include <terramap/pipeline/source.hpp>

#include <gtest/gtest.h>
#include <nlohmann/json.hpp>

#include <unistd.h>

#include <algorithm>
#include <atomic>
#include <cmath>
#include <filesystem>
#include <fstream>
#include <sstream>
#include <thread>

using namespace terramap;

namespace {
const std::string kTestDir = TERRAMAP_TEST_PLUGIN_DIR;
std::string lib(const std::string& n) { return kTestDir + "/" + n + ".so"; }
void expectHas(const std::string& msg, const std::string& part) {
  EXPECT_NE(msg.find(part), std::string::npos) << "expected '" << part << "' in:\n" << msg;
}
EngineOptions options(int threads = 2, Size size = Size(40, 30)) {
  EngineOptions o;
  o.geometry = Geometry(0.1, size);
  o.map.tile_size = 16;
  o.threads = threads;
  return o;
}
std::vector<std::string> validateText(const std::string& yaml) {
  const auto spec = parsePipelineString(yaml, "p.yaml", ".");
  PluginRegistry reg({kTestDir});
  return Engine::validate(spec, reg);
}
std::string joined(const std::vector<std::string>& v) {
  std::string s;
  for (const auto& e : v) s += e + "\n";
  return s;
}
}  // namespace

TEST(Engine, RunsStagesThatTakeTheEventInPipelineOrder) {
  Engine e(options());
  e.addStage("a", PluginRegistry::createFromFile(lib("test_probe")),
             {{"output_layer", std::string("a")}, {"events", std::vector<std::string>{"tick"}}});
  e.addStage("b", PluginRegistry::createFromFile(lib("test_probe")),
             {{"output_layer", std::string("b")}, {"input_layer", std::string("a")},
              {"events", std::vector<std::string>{"point_cloud"}}, {"increment", 3.0}});
  e.push(Tick{0.5});
  PointCloud pc;
  pc.stamp = 1.0;
  pc.points = {PointXYZI{NAN, 0, 0, 0}, PointXYZI{1, 2, 3, 0}};
  e.push(pc);
  e.push(Tick{1.5});
  const LayeredMap& m = e.map();
  EXPECT_EQ(m.at(m.layerId("a"), Index(5, 5)), 2.0f);
  EXPECT_EQ(m.at(m.layerId("b"), Index(5, 5)), 3.0f);
  const RunReport r = e.report();
  EXPECT_EQ(r.events.at("tick"), 2);
  EXPECT_EQ(r.events.at("point_cloud"), 1);
  ASSERT_EQ(r.stages.size(), 2u);
  EXPECT_EQ(r.stages[0].stats.events.at("tick"), 2);
  EXPECT_EQ(r.stages[1].stats.dropped.at("nan"), 1);
  EXPECT_DOUBLE_EQ(r.first_stamp, 0.5);
  EXPECT_DOUBLE_EQ(r.last_stamp, 1.5);
  const auto j = nlohmann::json::parse(reportToJson(r));
  EXPECT_EQ(j["stages"][1]["dropped"]["nan"], 1);
  EXPECT_EQ(j["dropped_total"], 1);
  EXPECT_EQ(j["events"]["tick"], 2);
  EXPECT_TRUE(j["stages"][0]["wall_s"].is_number());
}

TEST(Engine, RecordSinkTakesEveryRecordAndTheEngineKeepsOnlyTheirCount) {
  // Held (no sink): the records come back with report(). With a sink, each goes out right after
  // the call that reported it, in order, and the engine holds none of them: over an hour a run
  // reports ~15,000 sweep records of ~5 kB, which used to grow the process (the soak).
  auto probe = [] {
    return PluginRegistry::createFromFile(lib("test_probe"));
  };
  const std::map<std::string, ParamValue> params{{"records", true}, {"events", std::vector<std::string>{"tick"}}};
  Engine held(options());
  held.addStage("p", probe(), params);
  for (int k = 0; k < 3; ++k) held.push(Tick{0.1 * k});
  EXPECT_EQ(held.report().stages[0].stats.records.size(), 3u);
  EXPECT_EQ(held.report().stages[0].records_total, 3);

  Engine sunk(options());
  sunk.addStage("q", probe(), {{"output_layer", std::string("other")}});
  sunk.addStage("p", probe(), params);
  std::vector<std::pair<std::size_t, std::string>> got;
  sunk.setRecordSink([&](std::size_t stage, const std::string& json) { got.emplace_back(stage, json); });
  for (int k = 0; k < 5; ++k) {
    sunk.push(Tick{0.1 * k});
    ASSERT_EQ(got.size(), static_cast<std::size_t>(k + 1)) << "the record of event " << k << " went out at once";
    EXPECT_TRUE(sunk.report().stages[1].stats.records.empty());
  }
  sunk.finish();
  ASSERT_EQ(got.size(), 6u);
  for (int k = 0; k < 5; ++k) {
    EXPECT_EQ(got[static_cast<std::size_t>(k)].first, 1u);
    EXPECT_EQ(got[static_cast<std::size_t>(k)].second, "{\"type\":\"probe\",\"event\":" + std::to_string(k) + "}");
  }
  EXPECT_EQ(got[5].second, "{\"type\":\"probe.finish\",\"events\":5}");
  const RunReport r = sunk.report();
  EXPECT_TRUE(r.stages[1].stats.records.empty());
  EXPECT_EQ(r.stages[1].records_total, 6);
  EXPECT_EQ(r.stages[0].records_total, 0);
}

TEST(Report, SpooledRecordsWriteTheSameFileAsHeldOnes) {
  // runPipeline spools records to disk and streams them into report.json; the file must be the
  // one the in-memory writer gives: same records, order, indentation, the non-JSON record
  // wrapped, a record holding a newline, a stage without records.
  RunReport held;
  held.threads = 2;
  held.events["tick"] = 4;
  const std::vector<std::string> recs{"{\"a\":1,\"b\":[1,2.5,{\"c\":null}]}", "not json {", "{\"text\":\"x\\ny\"}",
                                      "{\n  \"pretty\": true\n}", "{}"};
  StageReport s0{"first", "t", "1", {}, 0};
  s0.stats.records = recs;
  s0.stats.dropped["nan"] = 2;
  StageReport s1{"second", "t", "1", {}, 0};
  StageReport s2{"third", "t", "1", {}, 0};
  s2.stats.records = {"{\"only\":\"held\"}", "{\"z\":[]}"};
  held.stages = {s0, s1, s2};
  const std::string extra = R"({"series": [{"t_s": 60}], "pipeline": "p.yaml"})";

  RunReport spooled = held;
  RecordSpool spool;
  spooled.stages[0].stats.records = {recs[0], recs[1]};  // some held: they come first
  for (std::size_t k = 2; k < recs.size(); ++k) spool.add(0, recs[k]);
  spooled.stages[0].records_total = static_cast<long>(recs.size());
  spooled.stages[2].stats.records = {s2.stats.records[0]};
  spool.add(2, s2.stats.records[1]);
  spooled.stages[2].records_total = 2;
  EXPECT_EQ(spool.count(0), 3);
  EXPECT_EQ(spool.count(1), 0);

  const auto dir = std::filesystem::temp_directory_path() / ("terramap_report_test_" + std::to_string(::getpid()));
  std::filesystem::create_directories(dir);
  const std::string a = (dir / "held.json").string(), b = (dir / "spooled.json").string();
  writeReport(held, a, extra);
  writeReport(spooled, b, extra, spool);
  auto text = [](const std::string& p) {
    std::ostringstream os;
    os << std::ifstream(p, std::ios::binary).rdbuf();
    return os.str();
  };
  EXPECT_EQ(text(a), text(b));
  const auto j = nlohmann::json::parse(text(b));
  EXPECT_EQ(j["stages"][0]["records"].size(), recs.size());
  EXPECT_EQ(j["stages"][0]["records"][1]["invalid_record"], "not json {");
  EXPECT_EQ(j["stages"][0]["records_total"], 5);
  EXPECT_TRUE(j["stages"][1]["records"].empty());
  EXPECT_EQ(j["series"][0]["t_s"], 60);
  // The spool can be written from twice (a report rewritten) and still appends afterwards.
  spool.add(0, "{\"late\":1}");
  EXPECT_EQ(spool.count(0), 4);
  long n = 0;
  spool.forEach(0, [&](const std::string&) { ++n; });
  EXPECT_EQ(n, 4);
  std::filesystem::remove_all(dir);
}

TEST(Engine, PluginThrowingInProcessIsNamed) {
  Engine e(options());
  e.addStage("boom", PluginRegistry::createFromFile(lib("test_probe")), {{"throw_on_event", 1L}});
  e.push(Tick{0});
  try {
    e.push(Tick{0.1});
    FAIL();
  } catch (const PluginError& err) {
    expectHas(err.what(), "stage 'boom' (test_probe) threw on tick at t=0.1");
    expectHas(err.what(), "probe asked to throw on event 1");
  }
}

TEST(Engine, ValidateCollectsEveryProblem) {
  const auto errs = validateText(R"(version: 1
map: {resolution: 0.1, size: [20, 20], tile: 16}
pipeline:
  - {name: a, type: test_probe, params: {events: [tick], output_layer: a}}
  - {name: a2, type: test_probe, params: {incremnt: 2, increment: x, output_layer: a2}}
  - {name: c, type: test_probe, params: {output_layer: c, input_layer: elevaton}}
  - {name: d, type: test_probe, params: {output_layer: a}}
  - {name: f, type: test_probe, params: {output_layer: f, increment: 1e9}}
  - {name: b, type: test_prob}
  - {name: e, type: bad_abi}
outputs: {geotiff: [nope]}
)");
  const std::string all = joined(errs);
  expectHas(all, "p.yaml:5:43: pipeline[1].params.incremnt: unknown parameter 'incremnt' for plugin 'test_probe' "
                 "(did you mean 'increment'?)");
  expectHas(all, "p.yaml:5:56: pipeline[1].params.increment: must be a number");
  expectHas(all, "p.yaml:9:21: pipeline[5].type: unknown plugin type 'test_prob' (did you mean 'test_probe'?)");
  expectHas(all, "stage 'c' reads layer 'elevaton' before any stage creates it");
  expectHas(all, "stage 'd' creates layer 'a', which already exists");
  expectHas(all, "ABI version mismatch: expected " + std::to_string(TERRAMAP_PLUGIN_ABI_VERSION) + ", found 99");
  expectHas(all, "pipeline[4].params.increment: must be in [-1e+06, 1e+06] (got 1e+09)");
  // After a stage of unknown type nobody knows which layers exist: 'nope' might be its.
  EXPECT_EQ(all.find("outputs.geotiff"), std::string::npos) << all;
  EXPECT_EQ(std::count(all.begin(), all.end(), '\n'), 7) << all;  // one line per problem
}

TEST(Engine, ValidateChecksOutputsWhenEveryStageIsKnown) {
  const std::string all = joined(validateText(R"(version: 1
map: {resolution: 0.1, size: [20, 20], tile: 16}
pipeline:
  - {name: a, type: test_probe, params: {output_layer: a}}
outputs: {geotiff: [nope]}
)"));
  expectHas(all, "outputs.geotiff: no stage creates layer 'nope'");
}

TEST(Engine, TypeErrorsShowTheValueGivenWithTheRightArticle) {
  const std::string all = joined(validateText(R"(version: 1
map: {resolution: 0.1, size: [20, 20], tile: 16}
pipeline:
  - {name: a, type: test_probe, params: {throw_on_event: abc, increment: [1, 2], output_layer: 7}}
)"));
  expectHas(all, "pipeline[0].params.throw_on_event: must be an integer (got 'abc')");
  expectHas(all, "pipeline[0].params.increment: must be a number (got [1, 2])");
  expectHas(all, "pipeline[0].params.output_layer: must be a string (got 7)");
  EXPECT_EQ(all.find("a integer"), std::string::npos) << all;
}

TEST(Engine, OneBadParameterGivesOneErrorNotFollowOnLayerErrors) {
  // Stage a's bad `increment` must not make the validator believe 'base' is never created:
  // b reads it and outputs export it, on other lines.
  const auto errs = validateText(R"(version: 1
map: {resolution: 0.1, size: [20, 20], tile: 16}
pipeline:
  - {name: a, type: test_probe, params: {output_layer: base, increment: x}}
  - {name: b, type: test_probe, params: {output_layer: b, input_layer: base}}
outputs: {geotiff: [base, b]}
)");
  ASSERT_EQ(errs.size(), 1u) << joined(errs);
  expectHas(errs[0], "p.yaml:4:62: pipeline[0].params.increment: must be a number (got 'x')");
}

TEST(Engine, EveryCrossCheckOfAPluginIsReportedAtOnce) {
  const auto errs = validateText(R"(version: 1
map: {resolution: 0.1, size: [20, 20], tile: 16}
pipeline:
  - {name: a, type: test_probe, params: {output_layer: q, input_layer: q, events: [tick, tock]}}
)");
  const std::string all = joined(errs);
  expectHas(all, "pipeline[0].params.events: unknown kind 'tock'");
  expectHas(all, "pipeline[0].params.input_layer: must differ from output_layer 'q'");
  EXPECT_EQ(errs.size(), 1u) << all;  // one ConfigError, two lines
  EXPECT_EQ(std::count(all.begin(), all.end(), '\n'), 2) << all;
}

TEST(Engine, ConfigErrorInStartOrFinishStaysAConfigError) {
  {
    Engine e(options());
    try {
      e.addStage("s", PluginRegistry::createFromFile(lib("test_probe")), {{"config_error_in", std::string("start")}});
      FAIL() << "start() should have thrown";
    } catch (const ConfigError& err) {
      expectHas(err.what(), "stage 's' (test_probe) in start(): probe: refused in start() on purpose");
    }
    EXPECT_TRUE(e.stageNames().empty());
  }
  Engine e(options());
  e.addStage("f", PluginRegistry::createFromFile(lib("test_probe")), {{"config_error_in", std::string("finish")}});
  try {
    e.finish();
    FAIL() << "finish() should have thrown";
  } catch (const ConfigError& err) {
    expectHas(err.what(), "stage 'f' (test_probe) in finish(): probe: refused in finish() on purpose");
  }
}

TEST(Engine, LayerDocsOfCreatedLayers) {
  Engine e(options());
  e.addStage("p", PluginRegistry::createFromFile(lib("test_probe")), {});
  EXPECT_EQ(e.layerDocs().at("probe"), "probe counter");
}

TEST(Engine, FromSpecBuildsAValidPipelineAndRefusesAnInvalidOne) {
  const auto spec = parsePipelineString(R"(version: 1
map: {resolution: 0.1, size: [20, 20], tile: 16}
threads: 1
pipeline:
  - {name: a, type: test_probe, params: {output_layer: a}}
)",
                                        "p.yaml", ".");
  auto e = Engine::fromSpec(spec, PluginRegistry({kTestDir}));
  EXPECT_EQ(e->stageNames(), std::vector<std::string>{"a"});
  auto bad = spec;
  bad.stages[0].params["output_layer"].value = 3L;
  EXPECT_THROW(Engine::fromSpec(bad, PluginRegistry({kTestDir})), ConfigError);
}

TEST(Engine, SnapshotIsConsistentWhileTheEngineKeepsWriting) {
  // The probe adds 1 to every cell per event, tile by tile. A consistent snapshot must
  // therefore hold one value everywhere, whatever moment the reader takes it.
  Engine e(options(2, Size(256, 256)));
  e.addStage("p", PluginRegistry::createFromFile(lib("test_probe")), {});
  std::atomic<bool> stop{false};
  std::atomic<int> snapshots{0}, inconsistent{0};
  std::thread reader([&] {
    while (!stop) {
      auto snap = e.snapshot();
      const LayerId id = snap->layerId("probe");
      const Eigen::MatrixXf m = snap->toMatrix(id);
      // Keep reading the same snapshot while the engine writes on.
      std::this_thread::yield();
      const Eigen::MatrixXf again = snap->toMatrix(id);
      if ((m.array() != m(0, 0)).any() || (again.array() != m.array()).any()) ++inconsistent;
      ++snapshots;
    }
  });
  // Write 400 events with snapshots taken in the middle of the run: one at least every 8 events.
  // The writer waits for a lagging reader rather than pushing on until it catches up, because a
  // mutex need not be fair: under ThreadSanitizer the writer re-took the lock for minutes.
  int pushed = 0;
  while (pushed < 400) {
    e.push(Tick{0.1 * pushed++});
    while (snapshots.load() < pushed / 8) std::this_thread::yield();
  }
  stop = true;
  reader.join();
  EXPECT_GE(snapshots.load(), 50);
  EXPECT_EQ(inconsistent.load(), 0);
  EXPECT_EQ(e.map().at(e.map().layerId("probe"), Index(100, 100)), static_cast<float>(pushed));
}

// The contract of engine.hpp: push() and editMap() on one thread, snapshot() on any. editMap()
// rewrites the whole layer cell by cell under the engine's lock, so every snapshot still holds
// one value everywhere. Without the lock a reader would catch a half-written layer (and
// ThreadSanitizer, Tsan.ThreadingContracts, a data race). One engine thread so that the only
// threads are the two the contract is about (TBB's own synchronisation is invisible to TSan).
TEST(Engine, EditMapAndPushOnOneThreadSnapshotsOnAnother) {
  Engine e(options(1, Size(64, 64)));
  e.addStage("p", PluginRegistry::createFromFile(lib("test_probe")), {});
  const LayerId id = e.map().layerId("probe");
  std::atomic<bool> stop{false};
  std::atomic<int> snapshots{0}, inconsistent{0};
  std::thread reader([&] {
    while (!stop) {
      const auto snap = e.snapshot();
      const Eigen::MatrixXf m = snap->toMatrix(id);
      if ((m.array() != m(0, 0)).any()) ++inconsistent;
      ++snapshots;
    }
  });
  // 200 rounds with a snapshot at least every 4 (the writer waits for a lagging reader, as above).
  for (int rounds = 0; rounds < 200;) {
    e.push(Tick{0.1 * rounds});
    const float v = static_cast<float>(1000 + rounds++);
    e.editMap([&](LayeredMap& m) {
      for (int i = 0; i < 64; ++i)
        for (int j = 0; j < 64; ++j) m.set(id, Index(i, j), v);
    });
    while (snapshots.load() < rounds / 4) std::this_thread::yield();
  }
  stop = true;
  reader.join();
  EXPECT_GE(snapshots.load(), 50);
  EXPECT_EQ(inconsistent.load(), 0);
}

namespace {
/// `count` Tick events 0.1 s apart; throws an InputError instead of event `fail_at` (if >= 0).
/// `produced` counts the events handed out so far (shared with the test).
std::atomic<long> g_produced{0};
class CountingSource : public Source {
 public:
  CountingSource(long count, long fail_at) : count_(count), fail_at_(fail_at) {}
  bool next(Event& e) override {
    if (k_ == fail_at_) throw InputError("counting source: event " + std::to_string(k_) + " is bad");
    if (k_ >= count_) return false;
    e = Tick{0.1 * static_cast<double>(k_++)};
    g_produced = k_;
    return true;
  }
  double progress() const override { return static_cast<double>(k_) / static_cast<double>(count_); }

 private:
  long count_, fail_at_, k_ = 0;
};
PipelineSpec countingSpec(int threads, long fail_at) {
  static const bool registered = [] {
    registerSource("test_counting", [](const PipelineSpec& s) {
      return std::make_unique<CountingSource>(static_cast<long>(sourceDouble(s.source, "count", true)),
                                              static_cast<long>(sourceDouble(s.source, "fail_at", false, -1.0)));
    });
    // As `--plugin-path` would: a pipeline file may not name plugin folders by itself.
    PluginRegistry::addTrustedPaths({kTestDir});
    return true;
  }();
  (void)registered;
  return parsePipelineString("version: 1\nmap: {resolution: 0.1, size: [20, 20], tile: 16}\nthreads: " +
                                 std::to_string(threads) + "\nsource: {type: test_counting, count: 400, fail_at: " +
                                 std::to_string(fail_at) + "}\npipeline:\n  - {name: a, type: test_probe, params: {output_layer: a}}\n"
                                 "outputs: {report: false, snapshot: false}\n",
                             "p.yaml", ".");
}
}  // namespace

TEST(Run, TheSourceRunsAheadOnItsOwnThreadAndItsProgressAndErrorsArriveInStep) {
  // With two threads the source produces events ahead of the stages (its own thread, a bounded
  // queue); the stages still see them in order, the progress passed on is the one of the event
  // being processed, and a source's error surfaces where it happened in the stream.
  const std::string out = (std::filesystem::temp_directory_path() / ("terramap_run_" + std::to_string(getpid()))).string();
  for (int threads : {1, 2}) {
    RunOptions o;
    o.out_dir = out;
    long ahead = 0, events = 0;
    double last_stamp = -1;
    bool in_order = true, progress_in_step = true;
    o.on_progress = [&](double p, long n) {
      events = n;
      // The first events take a while (a slow stage): time for a source ahead to fill its queue.
      if (n <= 3) std::this_thread::sleep_for(std::chrono::milliseconds(5));
      ahead = std::max(ahead, g_produced.load() - n);
      progress_in_step = progress_in_step && p == static_cast<double>(n) / 400.0;
    };
    o.on_event = [&](const LayeredMap&, double stamp) {
      in_order = in_order && stamp > last_stamp;
      last_stamp = stamp;
    };
    const RunResult r = runPipeline(countingSpec(threads, -1), o);
    EXPECT_EQ(events, 400);
    EXPECT_EQ(r.report.events.at("tick"), 400);
    EXPECT_TRUE(in_order);
    EXPECT_TRUE(progress_in_step) << threads << " threads";
    if (threads == 1) EXPECT_EQ(ahead, 0) << "one thread: the source is read as the stages need it";
    else EXPECT_GT(ahead, 1) << "two threads: the source runs ahead";

    RunOptions f;
    f.out_dir = out;
    long seen = 0;
    f.on_progress = [&](double, long n) { seen = n; };
    try {
      runPipeline(countingSpec(threads, 250), f);
      ADD_FAILURE() << "the source's error was lost";
    } catch (const InputError& e) {
      expectHas(e.what(), "event 250 is bad");
    }
    EXPECT_EQ(seen, 250) << "the stages processed every event before the bad one";
  }
  std::filesystem::remove_all(out);
}

// soil_oracle: the truth table's checks, the sweep's truth from it, one record per sweep with
// the truth (or the truth plus noise of the asked spread, the same for the same sweep),
// invalid where the blade was not cutting.
#include <gtest/gtest.h>

#include <terramap/core/error.hpp>
#include <terramap/soil/soil_parameters.hpp>

#include <cmath>
#include <filesystem>
#include <fstream>
#include <limits>

#include "soil_oracle.hpp"

using namespace terramap;
using namespace terramap::plugins;

namespace {

constexpr double kNaN = std::numeric_limits<double>::quiet_NaN();

std::string writeTable(const std::string& name, const std::string& text) {
  const std::string path = std::string(TERRAMAP_BINARY_DIR) + "/soil_oracle_test_" + name + ".json";
  std::ofstream(path) << text;
  return path;
}

// Loam until 1.0 s (not cutting at 0.5 s), clay from 2.0 s.
const char* kTable = R"({"t_s": [0.0, 0.5, 1.0, 2.0, 3.0],
  "soil": [[8000, 0.6, 2000, 0.4, 15000], null, [10000, 0.6, 2000, 0.4, 15000],
           [40000, 0.4, 12000, 0.3, 18000], [40000, 0.4, 12000, 0.3, 18000]]})";

std::string errorOf(const std::string& text) {
  try {
    loadSoilTruthTable(writeTable("bad", text));
  } catch (const InputError& e) {
    return e.what();
  }
  return "";
}

struct Harness {
  LayeredMap map{Geometry(0.1, Size(10, 10))};
  Executor ex{1};
  RecordBus bus;
  PluginStats stats;
  ProcessContext ctx{map, ex, bus, stats, "soil"};
  SoilOracle plugin;
  explicit Harness(std::map<std::string, ParamValue> params) {
    params.emplace("table", writeTable("table", kTable));
    plugin.configure(makeParams("soil", plugin.schema(), params));
    plugin.start(ctx);
  }
  void sweep(long index, double t0, double t1) {
    auto s = std::make_shared<SweepRecord>();
    s->sweep_index = index;
    s->t0 = t0;
    s->t1 = t1;
    bus.publish<SweepRecord>(SweepRecord::kType, t1, s);
  }
  // Every estimate published so far (the bus keeps only its last kHistory records, so the
  // tests read after each event).
  std::vector<SoilEstimateRecord> estimates() {
    plugin.process(ctx, Tick{});
    const RecordBus::Since got = bus.since(SoilEstimateRecord::kType, seen);
    EXPECT_EQ(got.missed, 0);
    for (const Record& r : got.records) {
      seen = r.sequence;
      published.push_back(*std::static_pointer_cast<const SoilEstimateRecord>(r.payload));
    }
    return published;
  }
  long seen = 0;
  std::vector<SoilEstimateRecord> published;
};

}  // namespace

TEST(SoilOracleTable, BadTablesNameTheFileAndTheRow) {
  EXPECT_NE(errorOf(R"({"t_s": [0, 1], "soil": [null]})").find("\"t_s\" has 2 rows, \"soil\" 1"), std::string::npos);
  EXPECT_NE(errorOf(R"({"t_s": [1, 0], "soil": [null, null]})").find("row 1 of \"t_s\""), std::string::npos);
  EXPECT_NE(errorOf(R"({"t_s": [0, 1], "soil": [null, [1, 2, 3]]})").find("row 1 of \"soil\": expected null or"),
            std::string::npos);
  EXPECT_NE(errorOf(R"({"t_s": [0], "soil": [[1, 2, "x", 4, 5]]})").find("'ca' is not a number"), std::string::npos);
  EXPECT_NE(errorOf(R"({"soil": []})").find("soil_oracle_test_bad.json: expected an object"), std::string::npos);
  EXPECT_NE(errorOf("{").find("not JSON"), std::string::npos);
  EXPECT_EQ(errorOf(kTable), "");
}

TEST(SoilOracleTable, ASweepTakesTheMeanOfTheCuttingRowsInsideItOrTheFirstRowAfter) {
  const SoilTruthTable t = loadSoilTruthTable(writeTable("table", kTable));
  // 0.0, 0.5 (not cutting) and 1.0: the mean of the two cutting rows.
  EXPECT_DOUBLE_EQ(truthOfSweep(t, 0.0, 1.0)[0], 9000.0);
  EXPECT_DOUBLE_EQ(truthOfSweep(t, 0.9, 2.5)[0], 25000.0);
  // No row inside (1.2 .. 1.8): the row at 2.0.
  EXPECT_DOUBLE_EQ(truthOfSweep(t, 1.2, 1.8)[0], 40000.0);
  // Only the not-cutting row inside: NaN, not the row after.
  EXPECT_TRUE(std::isnan(truthOfSweep(t, 0.4, 0.6)[0]));
  // After the table's end: NaN.
  EXPECT_TRUE(std::isnan(truthOfSweep(t, 3.5, 4.0)[0]));
}

TEST(SoilOracle, WithoutNoiseEachSweepGetsItsTruthAndNotCuttingIsInvalid) {
  Harness h({});
  h.sweep(1, 0.0, 1.0);
  h.sweep(2, 0.4, 0.6);
  h.sweep(3, 2.0, 3.0);
  const std::vector<SoilEstimateRecord> e = h.estimates();
  ASSERT_EQ(e.size(), 3u);
  EXPECT_EQ(e[0].sweep_index, 1);
  EXPECT_TRUE(e[0].valid);
  EXPECT_DOUBLE_EQ(e[0].mean[SoilEstimateRecord::kC], 9000.0);
  EXPECT_DOUBLE_EQ(e[0].mean[SoilEstimateRecord::kGamma], 15000.0);
  // The reported spread: 1 % of the range (c: 60 kPa).
  EXPECT_DOUBLE_EQ(e[0].var_total[SoilEstimateRecord::kC], 600.0 * 600.0);
  EXPECT_DOUBLE_EQ(e[0].beta_rad, 0.25 * 3.14159265358979323846 - 0.3);
  EXPECT_FALSE(e[1].valid);
  EXPECT_EQ(e[1].invalid_reason, "truth_not_cutting");
  EXPECT_EQ(h.stats.dropped["estimate_truth_not_cutting"], 1);
  EXPECT_DOUBLE_EQ(e[2].mean[SoilEstimateRecord::kC], 40000.0);
  EXPECT_EQ(h.estimates().size(), 3u);  // nothing new: nothing published again
}

TEST(SoilOracle, NoiseHasTheAskedSpreadIsTheSameForTheSameSweepAndStaysInRange) {
  const double sd_c = 5000.0, sd_phi = 0.5;  // phi's noise is far wider than its range: clamped
  Harness h({{"noise_sd", std::vector<double>{sd_c, sd_phi, 0, 0, 0}}, {"seed", 7L}});
  const int n = 2000;
  for (int k = 1; k <= n; ++k) {
    h.sweep(k, 2.0, 3.0);
    h.estimates();
  }
  const std::vector<SoilEstimateRecord> e = h.estimates();
  ASSERT_EQ(e.size(), static_cast<std::size_t>(n));
  double s1 = 0, s2 = 0;
  for (const SoilEstimateRecord& r : e) {
    const double d = r.mean[SoilEstimateRecord::kC] - 40000.0;
    s1 += d;
    s2 += d * d;
    EXPECT_GE(r.mean[SoilEstimateRecord::kPhi], soil::kSoilParams[soil::kParamPhi].lo);
    EXPECT_LE(r.mean[SoilEstimateRecord::kPhi], soil::kSoilParams[soil::kParamPhi].hi);
    EXPECT_DOUBLE_EQ(r.mean[SoilEstimateRecord::kCa], 12000.0);  // no noise asked: exact
  }
  const double mean = s1 / n, sd = std::sqrt(s2 / n - mean * mean);
  EXPECT_NEAR(mean, 0.0, 4 * sd_c / std::sqrt(n));
  EXPECT_NEAR(sd, sd_c, 0.1 * sd_c);
  EXPECT_DOUBLE_EQ(e[0].var_total[SoilEstimateRecord::kC], sd_c * sd_c);
  // The same sweep index in another run: the same draw; another seed: another.
  Harness again({{"noise_sd", std::vector<double>{sd_c, sd_phi, 0, 0, 0}}, {"seed", 7L}});
  again.sweep(5, 2.0, 3.0);
  EXPECT_EQ(again.estimates()[0].mean[SoilEstimateRecord::kC], e[4].mean[SoilEstimateRecord::kC]);
  Harness other({{"noise_sd", std::vector<double>{sd_c, sd_phi, 0, 0, 0}}, {"seed", 8L}});
  other.sweep(5, 2.0, 3.0);
  EXPECT_NE(other.estimates()[0].mean[SoilEstimateRecord::kC], e[4].mean[SoilEstimateRecord::kC]);
}

TEST(SoilOracle, AMissingTableIsAConfigErrorNamingTheKey) {
  SoilOracle p;
  try {
    p.configure(makeParams("soil", p.schema(), {{"table", std::string("/nonexistent/oracle.json")}}));
    FAIL() << "no error";
  } catch (const ConfigError& e) {
    EXPECT_NE(std::string(e.what()).find("table"), std::string::npos) << e.what();
    EXPECT_NE(std::string(e.what()).find("/nonexistent/oracle.json"), std::string::npos) << e.what();
  }
}

#include "soil_oracle.hpp"

#include <terramap/core/error.hpp>
#include <terramap/soil/publish_estimate.hpp>
#include <terramap/soil/soil_parameters.hpp>

#include <nlohmann/json.hpp>

#include <algorithm>
#include <cmath>
#include <fstream>
#include <random>

namespace terramap::plugins {

namespace {

constexpr int kN = SoilEstimateRecord::kCount;

}  // namespace

SoilTruthTable loadSoilTruthTable(const std::string& path) {
  std::ifstream in(path);
  if (!in) throw InputError(path + ": cannot open the soil truth table");
  nlohmann::json j;
  try {
    j = nlohmann::json::parse(in);
  } catch (const nlohmann::json::exception& e) {
    throw InputError(path + ": not JSON: " + e.what());
  }
  if (!j.is_object() || !j.contains("t_s") || !j.contains("soil") || !j["t_s"].is_array() || !j["soil"].is_array())
    throw InputError(path + ": expected an object with arrays \"t_s\" and \"soil\"");
  const nlohmann::json &t = j["t_s"], &s = j["soil"];
  if (t.size() != s.size())
    throw InputError(path + ": \"t_s\" has " + std::to_string(t.size()) + " rows, \"soil\" " + std::to_string(s.size()));
  SoilTruthTable tab;
  tab.t_s.reserve(t.size());
  tab.soil.reserve(t.size());
  for (std::size_t r = 0; r < t.size(); ++r) {
    const std::string row = path + ": row " + std::to_string(r);
    if (!t[r].is_number() || !std::isfinite(t[r].get<double>())) throw InputError(row + " of \"t_s\": not a finite number");
    const double tr = t[r].get<double>();
    if (r > 0 && tr < tab.t_s.back())
      throw InputError(row + " of \"t_s\": " + std::to_string(tr) + " s comes before the row above (" +
                       std::to_string(tab.t_s.back()) + " s); rows must be in time order");
    SoilEstimateRecord::SoilVector v;
    v.fill(SoilEstimateRecord::kNaN);
    if (!s[r].is_null()) {
      if (!s[r].is_array() || s[r].size() != static_cast<std::size_t>(kN))
        throw InputError(row + " of \"soil\": expected null or [c, phi, ca, delta, gamma]");
      for (int k = 0; k < kN; ++k) {
        const nlohmann::json& x = s[r][static_cast<std::size_t>(k)];
        if (!x.is_null() && !x.is_number())
          throw InputError(row + " of \"soil\": '" + soil::kSoilParams[k].name + "' is not a number");
        if (x.is_number()) v[static_cast<std::size_t>(k)] = x.get<double>();
      }
    }
    tab.t_s.push_back(tr);
    tab.soil.push_back(v);
  }
  return tab;
}

SoilEstimateRecord::SoilVector truthOfSweep(const SoilTruthTable& tab, double t0, double t1) {
  SoilEstimateRecord::SoilVector sum{};
  int n = 0;
  const auto first = std::lower_bound(tab.t_s.begin(), tab.t_s.end(), t0);
  const auto finite = [](const SoilEstimateRecord::SoilVector& v) {
    return std::all_of(v.begin(), v.end(), [](double x) { return std::isfinite(x); });
  };
  auto r = static_cast<std::size_t>(first - tab.t_s.begin());
  bool inside = false;
  for (; r < tab.t_s.size() && tab.t_s[r] <= t1; ++r) {
    inside = true;
    if (!finite(tab.soil[r])) continue;
    for (int k = 0; k < kN; ++k) sum[static_cast<std::size_t>(k)] += tab.soil[r][static_cast<std::size_t>(k)];
    ++n;
  }
  SoilEstimateRecord::SoilVector out;
  out.fill(SoilEstimateRecord::kNaN);
  if (n > 0) {
    for (int k = 0; k < kN; ++k) out[static_cast<std::size_t>(k)] = sum[static_cast<std::size_t>(k)] / n;
  } else if (!inside && r < tab.t_s.size() && finite(tab.soil[r])) {
    out = tab.soil[r];  // no row inside the sweep: the first one after it
  }
  return out;
}

ParamSchema SoilOracle::schema() const {
  ParamSpec table = param::path("table", "", "soil truth table (JSON, see soil_oracle.hpp); relative to the pipeline's folder");
  table.default_value.reset();  // required
  return {table,
          param::reals("noise_sd", {0, 0, 0, 0, 0}, kN, 0.0, 1e9, "SI",
                       "standard deviation of the noise added to [c, phi, ca, delta, gamma] (Pa, rad, Pa, rad, N/m^3)"),
          param::real("min_sd_fraction", 0.01, 1e-6, 1.0, "1",
                      "smallest reported standard deviation, as a fraction of each property's physical range"),
          param::integer("seed", 1, 0, 1L << 62, "seed of the noise (drawn per sweep index)")};
}

void SoilOracle::configure(const Params& p) {
  const std::string path = p.getString("table");
  if (path.empty()) p.fail("table", "the path of a soil truth table is required");
  try {
    table_ = loadSoilTruthTable(path);
  } catch (const InputError& e) {
    p.fail("table", e.what());
  }
  const std::vector<double>& sd = p.getDoubles("noise_sd");
  std::copy(sd.begin(), sd.end(), noise_sd_.begin());
  min_sd_fraction_ = p.getDouble("min_sd_fraction");
  seed_ = p.getInt("seed");
}

void SoilOracle::start(ProcessContext& ctx) {
  // A sweep published before this stage existed is not ours to estimate (as soil_pinn).
  const Record* r = ctx.records().latest(SweepRecord::kType);
  last_sequence_ = r ? r->sequence : 0;
}

SoilEstimateRecord SoilOracle::estimate(const SweepRecord& sweep) const {
  SoilEstimateRecord r = soilEstimateRecordFor(sweep);
  r.members = 1;
  const SoilEstimateRecord::SoilVector truth = truthOfSweep(table_, sweep.t0, sweep.t1);
  if (!std::isfinite(truth[0])) {
    r.invalid_reason = "truth_not_cutting";
    return r;
  }
  // One generator per sweep: its draw does not depend on which other sweeps the run had.
  std::seed_seq seq{static_cast<std::uint64_t>(seed_), static_cast<std::uint64_t>(sweep.sweep_index)};
  std::mt19937_64 gen(seq);
  for (int k = 0; k < kN; ++k) {
    const soil::SoilParamInfo& info = soil::kSoilParams[k];
    const auto q = static_cast<std::size_t>(k);
    const double noise = noise_sd_[q] > 0 ? std::normal_distribution<double>(0.0, noise_sd_[q])(gen) : 0.0;
    r.mean[q] = std::clamp(truth[q] + noise, info.lo, info.hi);
    const double sd = std::max(noise_sd_[q], min_sd_fraction_ * (info.hi - info.lo));
    r.var_total[q] = r.var_nullspace[q] = sd * sd;
    r.var_aleatoric[q] = sd * sd;
    r.var_epistemic[q] = 0.0;
  }
  r.beta_rad = 0.25 * 3.14159265358979323846 - 0.5 * r.mean[SoilEstimateRecord::kPhi];
  r.d_res_m = 0.0;
  r.beta_res_rad = 0.0;
  r.valid_members = 1;
  r.valid = true;
  return r;
}

void SoilOracle::collect(ProcessContext& ctx) {
  const RecordBus::Since got = ctx.records().since(SweepRecord::kType, last_sequence_);
  if (got.missed > 0) ctx.countDrop("sweep_missed", got.missed);
  for (const Record& rec : got.records) {
    last_sequence_ = rec.sequence;
    const auto& sweep = *std::static_pointer_cast<const SweepRecord>(rec.payload);
    auto e = std::make_shared<const SoilEstimateRecord>(estimate(sweep));
    ctx.addCounter("sweeps", 1);
    soil::publishEstimate(ctx, e);
  }
}

void SoilOracle::process(ProcessContext& ctx, const Event&) { collect(ctx); }

void SoilOracle::finish(ProcessContext& ctx) { collect(ctx); }  // blade_sweep's finish() may cut a last sweep

}  // namespace terramap::plugins

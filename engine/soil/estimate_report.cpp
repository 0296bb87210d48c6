#include <terramap/soil/estimate_report.hpp>

#include <nlohmann/json.hpp>

#include <cmath>

namespace terramap::soil {

namespace {

nlohmann::json num(double v) { return std::isfinite(v) ? nlohmann::json(v) : nlohmann::json(nullptr); }

template <std::size_t N>
nlohmann::json nums(const std::array<double, N>& a) {
  nlohmann::json j = nlohmann::json::array();
  for (double v : a) j.push_back(num(v));
  return j;
}

}  // namespace

std::string estimateReportJson(const SoilEstimateRecord& r) {
  nlohmann::json j;
  j["type"] = SoilEstimateRecord::kType;
  j["sweep_index"] = r.sweep_index;
  j["machine_id"] = r.machine_id;
  j["t1"] = num(r.t1);
  j["stamp"] = num(r.stamp);
  j["valid"] = r.valid;
  if (!r.valid) j["invalid_reason"] = r.invalid_reason;
  j["valid_members"] = r.valid_members;
  j["mean"] = nums(r.mean);
  std::array<double, SoilEstimateRecord::kCount> sd{};
  for (int k = 0; k < SoilEstimateRecord::kCount; ++k) sd[k] = std::sqrt(r.var_total[k]);
  j["sd_total"] = nums(sd);
  j["F_r"] = nums(r.F_r);
  j["F_pred"] = nums(r.F_pred);
  j["F_measured"] = nums(r.F_measured);
  return j.dump();
}

}  // namespace terramap::soil

#pragma once
/// \file
/// What a soil estimator stage (soil_pinn, soil_oracle) does with each estimate it makes:
/// counts it (`estimates`; an invalid one also as `estimates_invalid` and a drop named
/// `estimate_<invalid_reason>`), writes its report line (estimateReportJson) and publishes it on
/// the bus at its stamp for the stages after (soil_bayes, octomap_strata). On the stage's calling
/// thread, as every ProcessContext use. Header-only: the caller links the plugin API and
/// terramap::soil.
#include <terramap/plugin/plugin.hpp>
#include <terramap/soil/estimate_report.hpp>

#include <memory>

namespace terramap::soil {

inline void publishEstimate(ProcessContext& ctx, const std::shared_ptr<const SoilEstimateRecord>& rec) {
  ctx.addCounter("estimates", 1);
  if (!rec->valid) {
    ctx.addCounter("estimates_invalid", 1);
    ctx.countDrop("estimate_" + rec->invalid_reason);
  }
  ctx.reportRecord(estimateReportJson(*rec));
  ctx.records().publish<SoilEstimateRecord>(SoilEstimateRecord::kType, rec->stamp, rec);
}

}  // namespace terramap::soil

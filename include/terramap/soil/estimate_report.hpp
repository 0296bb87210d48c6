#pragma once
/// \file
/// The compact JSON object a soil estimator stage puts in the run report (report.json's
/// "records") for one SoilEstimateRecord: which sweep (type, sweep_index, machine_id, t1,
/// stamp), valid (and invalid_reason), valid_members, mean, sd_total (square roots of
/// var_total), F_r, F_pred, F_measured; SI units as in the record, NaN written as null.
/// soil_pinn and soil_oracle both write it; eval-strata reads it. Pure, thread-safe.
#include <terramap/plugin/records/soil_estimate_record.hpp>

#include <string>

namespace terramap::soil {

std::string estimateReportJson(const SoilEstimateRecord& r);

}  // namespace terramap::soil

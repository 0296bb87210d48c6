#include "soil_pinn_plugin.hpp"

#include <terramap/core/error.hpp>
#include <terramap/soil/publish_estimate.hpp>
#include <terramap/soil/fee.hpp>

#include <ATen/Parallel.h>

#include <cmath>

namespace terramap::plugins {

SoilEstimateRecord soilEstimateRecord(const SweepRecord& sweep, const soil::PinnSample& sample,
                                      const pinn::SoilEstimate& e, int members) {
  SoilEstimateRecord r = soilEstimateRecordFor(sweep);
  r.stamp = sample.anchor_stamp;
  r.history_T = sample.T;
  r.horizon_P = sample.P;
  r.d_res_m = e.d_res_m;
  r.beta_res_rad = e.beta_res_rad;
  r.beta_rad = e.beta_rad;
  bool finite = true;
  for (int k = 0; k < SoilEstimateRecord::kCount; ++k) {
    r.mean[k] = e.mean[k];
    r.var_total[k] = e.var_total[k];
    r.var_aleatoric[k] = e.var_aleatoric[k];
    r.var_nullspace[k] = e.var_nullspace[k];
    r.var_epistemic[k] = e.var_epistemic[k];
    finite = finite && std::isfinite(r.mean[k]) && std::isfinite(r.var_total[k]);
  }
  r.F_r = e.F_r;
  if (!e.F.empty()) r.F_pred = e.F.back();
  if (sample.P > 0 && sample.force.size() >= static_cast<std::size_t>(2 * sample.P)) {
    const std::size_t last = static_cast<std::size_t>(sample.P - 1) * 2;
    r.F_measured = {sample.force[last], sample.force[last + 1]};
  }
  r.members = members;
  r.valid_members = e.valid_members;
  if (!e.valid)
    r.invalid_reason = "fee_invalid_majority";
  else if (!finite)
    r.invalid_reason = "non_finite_output";
  r.valid = r.invalid_reason.empty();
  return r;
}

ParamSchema SoilPinn::schema() const {
  ParamSpec model = param::path("model", "",
                                "trained soil estimator file (saveEstimator; required); relative to the pipeline's folder");
  model.default_value.reset();  // required
  const pinn::NullspaceTolerances d;
  return {model,
          param::real("nullspace_a_tol", d.a_tol, 0.0, 1e12, "1",
                      "Eq. 7 absolute singular-value threshold of the force Jacobian (SI units)"),
          param::real("nullspace_r_tol", d.r_tol, 0.0, 1.0, "1",
                      "Eq. 7 singular-value threshold relative to the largest"),
          param::integer("history_capacity", 0, 0, 1000000,
                         "observations kept per machine; 0: the model's T + 64 (what the dataset keeps); else >= T")};
}

void SoilPinn::configure(const Params& p) {
  model_path_ = p.getString("model");
  tol_.a_tol = p.getDouble("nullspace_a_tol");
  tol_.r_tol = p.getDouble("nullspace_r_tol");
  if (model_path_.empty()) p.fail("model", "the path of a trained soil estimator file is required");
  try {
    estimator_ = std::make_shared<const pinn::SoilEstimator>(pinn::loadEstimator(model_path_));
  } catch (const Error& ex) {  // loadEstimator's InputError names the file
    p.fail("model", std::string("cannot load the soil estimator: ") + ex.what());
  } catch (const std::exception& ex) {  // anything libtorch throws past loadEstimator
    p.fail("model", std::string("cannot load the soil estimator '") + model_path_ + "': " + ex.what());
  }
  const int T = estimator_->T();
  if (estimator_->P() > T)
    p.fail("model", "'" + model_path_ + "': horizon P " + std::to_string(estimator_->P()) + " exceeds history T " +
                        std::to_string(T));
  const long cap = p.getInt("history_capacity");
  if (cap != 0 && cap < T)
    p.fail("history_capacity", "must be 0 or at least the model's T (" + std::to_string(T) + ")");
  history_capacity_ = cap == 0 ? static_cast<std::size_t>(T) + 64 : static_cast<std::size_t>(cap);
}

void SoilPinn::start(ProcessContext& ctx) {
  pending_.start(ctx);
  ctx.addCounter("model_members", static_cast<double>(estimator_->size()));
}

void SoilPinn::estimateSweep(ProcessContext& ctx, const SweepRecord& sweep) {
  soil::PinnSample sample;
  auto it = pending_.histories().find(sweep.machine_id);
  const soil::SampleSkip why = it == pending_.histories().end()
      ? soil::SampleSkip::ShortHistory
      : soil::buildSample(it->second, sweep, estimator_->T(), estimator_->P(), sample);
  if (why != soil::SampleSkip::None) {
    ctx.countDrop(std::string("sweep_") + soil::sampleSkipName(why));
    return;
  }
  // On the calling (engine) thread, without libtorch (README, "Threading" and "Latency").
  // A model trained on the cut's cross-section reads d and w as its one wedge; the record keeps
  // the sweep's own geometry.
  pinn::SoilEstimate e;
  if (estimator_->slicedGeometry() && sample.profile.size() == sample.theta_k.size() / soil::kThetaK * soil::kProfile) {
    soil::PinnSample sliced = sample;
    soil::applySlicedGeometry(sliced.theta_k.data(), sliced.profile.data(), sliced.P);
    e = estimator_->estimateFast(sliced, tol_);
  } else {
    e = estimator_->estimateFast(sample, tol_);
  }
  auto rec = std::make_shared<const SoilEstimateRecord>(
      soilEstimateRecord(sweep, sample, e, static_cast<int>(estimator_->size())));
  soil::publishEstimate(ctx, rec);
}

void SoilPinn::process(ProcessContext& ctx, const Event& event) {
  pending_.process(ctx, event, history_capacity_, [&](const SweepRecord& s) { estimateSweep(ctx, s); });
}

void SoilPinn::finish(ProcessContext& ctx) {
  pending_.finish(ctx, [&](const SweepRecord& s) { estimateSweep(ctx, s); });
}

}  // namespace terramap::plugins

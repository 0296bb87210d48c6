#pragma once
/// \file
/// soil_pinn: the PINN soil estimator as a pipeline stage (ALGORITHMS.md §F; paper §2.1).
///
/// Consumes the machine's Observation stream (the history the network reads) and the
/// `blade_sweep` plugin's SweepRecord (the FEE geometry Θ_k), and publishes one
/// SoilEstimateRecord (terramap/plugin/records/soil_estimate_record.hpp) per sweep that gives a
/// sample. The sample is built by soil::buildSample, the same function the training dataset
/// (`terramap dataset`) uses, with the model's T and P; the estimate is the model file's
/// SoilEstimator (estimator.hpp). Writes no layers.
///
/// Order: `blade_sweep` must be an earlier stage (it publishes the SweepRecord in the same
/// BladePose event). After every event the plugin looks at the latest SweepRecord's sequence;
/// a new sweep waits (pending) until an observation of its machine with stamp >= t1 has
/// arrived, since the simulator and real drivers may deliver the observation of an instant
/// after that instant's BladePose; pending sweeps left at finish() are built with what the
/// history holds then.
///
/// Threading: estimates run on the calling (engine) thread with at::set_num_threads(1) (see
/// the README's "Threading"); results do not depend on the engine's thread count.
#include <terramap/plugin/plugin.hpp>
#include <terramap/plugin/records/soil_estimate_record.hpp>
#include <terramap/plugin/records/sweep_record.hpp>
#include <terramap/soil/pending_sweeps.hpp>
#include <terramap/soil/pinn_sample.hpp>

#include "estimator.hpp"

#include <map>
#include <memory>
#include <string>
#include <vector>

namespace terramap::plugins {

/// The record of one estimate (pure: the plugin and the tests share it).
SoilEstimateRecord soilEstimateRecord(const SweepRecord& sweep, const soil::PinnSample& sample,
                                      const pinn::SoilEstimate& estimate, int members);

class SoilPinn : public Plugin {
 public:
  ParamSchema schema() const override;
  /// Loads the model file (so a bad path fails while the pipeline is validated).
  /// \throws ConfigError naming the file when it is missing or not a soil estimator, or when
  /// history_capacity is below the model's T.
  void configure(const Params& params) override;
  std::vector<LayerSpec> layers() const override { return {}; }
  EventMask events() const override { return EventKind::Observation | EventKind::BladePose; }
  void start(ProcessContext& ctx) override;
  void process(ProcessContext& ctx, const Event& event) override;
  void finish(ProcessContext& ctx) override;

  const pinn::SoilEstimator& estimator() const { return *estimator_; }
  std::size_t pendingSweeps() const { return pending_.size(); }

 private:
  void estimateSweep(ProcessContext& ctx, const SweepRecord& sweep);

  std::string model_path_;
  pinn::NullspaceTolerances tol_;
  std::size_t history_capacity_ = 0;
  std::shared_ptr<const pinn::SoilEstimator> estimator_;
  soil::PendingSweeps pending_;
};

}  // namespace terramap::plugins

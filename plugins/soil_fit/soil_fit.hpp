#pragma once
/// \file
/// soil_fit: the soil fitted jointly to the force of the machine's last sweeps, as a pipeline
/// stage that takes soil_pinn's place (docs/soil_estimator.md, "Where the error lives").
///
/// Why: one sweep's force does not tell φ from c: soil_pinn's φ has no skill (correlation with
/// the truth −0.15 on the test split), and averaging per-sweep estimates in the map cannot
/// recover what no estimate holds. Rows of many sweeps in one soil do tell it (a joint fit of an
/// episode's rows: φ correlation 0.68 on the mapped geometry, 0.90 on the simulator's:
/// scripts/analysis/soil_joint_fit.py).
///
/// Per SweepRecord of `blade_sweep` (once the observation at its last pose has arrived, as
/// soil_pinn waits), the sample of soil::buildSample (T = P = `horizon`) gives `horizon` rows:
/// the mapped geometry Θ_k, the measured force, and whether the edge was seen descending (the
/// observation's blade_vz_map_mps < 0). Rows where the machine stood stalled are left out (its
/// force is what the tracks mobilised, not the soil's failure). The rows of the machine's last
/// `window_sweeps` sweeps whose blade ended within `window_m` of this one's are fitted jointly
/// (soil::fitPooled, warm-started from the machine's previous fit) and published as this
/// sweep's SoilEstimateRecord, so soil_bayes, fee_index and octomap_strata read it as they read
/// soil_pinn's. Variances: the (residual-scaled) Gauss-Newton covariance's diagonal times the number of sweeps in
/// the window (each sweep's rows enter that many consecutive fits, and soil_bayes fuses every
/// one of them), as var_total, var_aleatoric and var_nullspace; no epistemic part.
///
/// Order: `blade_sweep` must be an earlier stage. Threading: all work on the calling (engine)
/// thread; results do not depend on the engine's thread count. Writes no layers.
#include <terramap/plugin/plugin.hpp>
#include <terramap/plugin/records/soil_estimate_record.hpp>
#include <terramap/plugin/records/sweep_record.hpp>
#include <terramap/soil/pending_sweeps.hpp>
#include <terramap/soil/pinn_sample.hpp>

#include "pooled_fit.hpp"

#include <deque>
#include <map>
#include <memory>
#include <string>
#include <vector>

namespace terramap::plugins {

/// The fit rows of one sample (stalled rows and rows without a cut left out).
std::vector<soil::FitRow> fitRows(const soil::PinnSample& sample);

class SoilFit : public Plugin {
 public:
  ParamSchema schema() const override;
  void configure(const Params& params) override;
  std::vector<LayerSpec> layers() const override { return {}; }
  EventMask events() const override { return EventKind::Observation | EventKind::BladePose; }
  void start(ProcessContext& ctx) override;
  void process(ProcessContext& ctx, const Event& event) override;
  void finish(ProcessContext& ctx) override;

 private:
  struct WindowSweep {
    Eigen::Vector3d edge;
    std::vector<soil::FitRow> rows;
  };
  struct MachineState {
    std::deque<WindowSweep> window;
    soil::SoilParamVector last{};
    bool has_last = false;
  };
  void estimateSweep(ProcessContext& ctx, const SweepRecord& sweep);

  int horizon_ = 10, window_sweeps_ = 10, min_rows_ = 10;
  double window_m_ = 2.0;
  soil::PooledFitOptions opt_;
  std::map<std::string, MachineState> machines_;
  soil::PendingSweeps pending_;
};

}  // namespace terramap::plugins

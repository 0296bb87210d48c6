#pragma once
/// \file
/// How good the soil estimator is on a dataset split (`terramap eval-soil`; paper Fig. 11 and
/// §3.1): force error, soil-property errors against the simulator's truth, calibration of each
/// kind of variance, and the epistemic spread that should grow on the held-out soil and rake.
#include "estimator.hpp"
#include "trainer.hpp"

#include <terramap/io/chart.hpp>

#include <array>
#include <cmath>
#include <string>
#include <vector>

namespace terramap::pinn {

/// One force model's error against the simulator's noise-free force F_q over a set of horizon
/// rows: 100 Σ‖F̂ − F_q‖ / Σ‖F_q‖, and its parts along x (the sweep direction) and z (up),
/// 100 Σ|F̂x − F_qx| / Σ‖F_q‖ and 100 Σ|F̂z − F_qz| / Σ‖F_q‖. NaN without rows.
struct ForceGap {
  double total = NAN, x = NAN, z = NAN;
};

/// Where the estimator's force error lives (docs/soil_estimator.md, "Where the error
/// lives"), on the horizon rows whose noise-free force and per-row truth the dataset holds:
///  (a) the physics layer with the truth soil on the simulator's own geometry of each row
///      (sim::FeeTruth: one wedge at the depth-weighted depth over the cutting width),
///  (b) the same physics layer with the truth soil on the mapped geometry (theta_k),
///  (c) the estimator.
/// (a) is the model class (the simulator's force against the layer's physics), (b) − (a) the
/// geometry extraction, (c) − (b) the estimator. "The physics layer" is the FEE's paper F at β*
/// plus the edge's penetration resistance on rows the observations show descending (the
/// committed model's layer without its residuals). The ladders add the terms the simulator has
/// one at a time; the part-by-part rows compare each modelled term with the simulator's own.
struct ForceDecomposition {
  long rows = 0, moving_rows = 0;
  ForceGap truth_geometry, mapped_geometry, estimator;                      ///< (a), (b), (c)
  ForceGap truth_geometry_moving, mapped_geometry_moving, estimator_moving;  ///< over moving rows
  /// On the truth / mapped geometry: [0] paper F at β*, [1] + penetration where the observed
  /// edge descends (= (a) / (b)), [2] + adhesion on the blade face (F_total), [3] + the inertia
  /// of the soil entering the wedge (γ/g d w v², v the observed edge speed).
  std::array<ForceGap, 4> ladder_truth{}, ladder_mapped{};
  /// (a) and (b) with the penetration gate at the edge's true vertical speed (the simulator's)
  /// instead of the observed one: what the gate's errors cost the physics layer.
  ForceGap truth_geometry_true_gate, mapped_geometry_true_gate;
  /// Part by part on the truth geometry, each against the simulator's own part (same norm
  /// Σ‖F_q‖): F_total of one wedge at the summary geometry against the FEE summed over the
  /// slices as mobilised; the penetration term against the simulator's; the inertia term
  /// against the simulator's.
  ForceGap wedge_vs_slices, penetration_term, inertia_term;
  /// Σ‖part‖ / Σ‖F_q‖ of the simulator's parts: FEE over the slices, inertia, penetration.
  double share_fee = NAN, share_inertia = NAN, share_penetration = NAN;
  /// Rows the observations show descending, and among them those whose edge truly descended;
  /// rows whose edge truly descended.
  long observed_descending = 0, observed_descending_true = 0, true_descending = 0;
};

struct SplitMetrics {
  std::string split;
  long samples = 0, valid = 0;  ///< samples, and those the estimator called valid
  /// 100 Σ‖F̂ − F‖ / Σ‖F‖ over valid samples and horizon steps (F measured, F̂ predicted).
  double force_error_pct = 0;
  /// The same error of the FEE evaluated with the TRUTH soil on the sample's extracted geometry
  /// (paper's F, Rankine beta, no residuals): how much of the force the physics layer could
  /// explain with perfect soil knowledge; and of a constant force (the split's mean).
  double force_error_truth_fee_pct = 0, force_error_mean_pct = 0;
  /// The estimator's force error over the horizon rows where the machine was moving (not
  /// soil::stalledRow), the rows training fits; and the share of rows left out.
  double force_error_moving_pct = 0, stalled_row_fraction = 0;
  /// 100 Σ|F̂x − Fx| / Σ‖F‖ and the same along z (up): where the force error lies.
  double force_error_x_pct = 0, force_error_z_pct = 0;
  /// As force_error_truth_fee_pct but the paper's F at beta* (the angle the simulator's wedge
  /// fails at, the physics layer's default base angle): what the layer could explain with the
  /// truth soil and no residuals.
  double force_error_truth_fee_min_pct = 0;
  /// And with the truth soil on the simulator's own geometry of the cut (sim::FeeTruth), over the
  /// samples where it is known: what is left is the simulator's force beyond the paper's F
  /// (adhesion on the face, inertia, penetration, mobilisation, noise).
  double force_error_truth_geometry_pct = 0;
  /// The simulator's own force model on that geometry: F_total at beta* (what the simulator
  /// computes before inertia, penetration, mobilisation and noise).
  double force_error_simulator_model_pct = 0;
  long truth_geometry_samples = 0;
  /// The floor of force_error_pct: the same error of the simulator's force without its noise
  /// (coloured soil noise and the sensor's), i.e. of an estimator that predicted the soil's force
  /// exactly; and the estimator's error against that noise-free force, 100 Σ‖F̂ − F_q‖ / Σ‖F_q‖.
  /// Over the rows where the dataset has the noise-free force (NaN for files without it).
  double force_error_noise_floor_pct = NAN, force_error_noise_free_pct = NAN;
  long noise_free_rows = 0;
  /// Median of the mapped surcharge Q over the simulator's at the same sweep (NaN without any).
  double surcharge_ratio_median = NAN;
  /// Median over rows of mapped / simulator's depth, width and surcharge (per row, rows where
  /// both are positive; NaN without per-row truth).
  double depth_ratio_row_median = NAN, width_ratio_row_median = NAN, surcharge_ratio_row_median = NAN;
  ForceDecomposition decomposition;
  std::array<double, kSoilCount> mae{};        ///< |mean − truth|, SI units
  std::array<double, kSoilCount> bias{};       ///< mean − truth
  /// Skill against ignorance: the MAE of a constant estimate, the training split's median truth
  /// (NaN without a training split), and the Pearson correlation of estimate with truth over
  /// the valid samples (NaN when either does not vary). An estimator whose MAE is not clearly
  /// below mae_constant, or whose correlation is near 0, has not learnt that property.
  std::array<double, kSoilCount> mae_constant{}, correlation{};
  /// Fraction of valid samples whose truth lies within ±1σ, per variance kind.
  std::array<double, kSoilCount> coverage_aleatoric{}, coverage_nullspace{}, coverage_total{};
  std::array<double, kSoilCount> mean_var_aleatoric{}, mean_var_epistemic{}, mean_var_total{};
  /// Valid samples whose inputs lie beyond the training split's 99th percentile of input
  /// distance (soil::PinnInputDistance; share > 0), as a fraction, and the mean share of the
  /// prior variance added (NaN for a model without the statistics).
  double input_beyond_fraction = NAN, input_share_mean = NAN;
};

/// One row of the Fig. 11 analogue: estimates binned by family and I_d (10 bins of 0.1).
struct Fig11Bin {
  int family = 0;      ///< soil::SoilFamily
  int bin = 0;         ///< I_d in [bin/10, (bin+1)/10)
  long samples = 0;
  std::array<double, kSoilCount> truth{}, mean{}, sigma{};  ///< averages over the bin; sigma = sqrt(mean var_total)
};

/// Does Fig. 11's estimate rise with relative density where the truth does? Per soil family, over
/// its Fig11Bin rows (those with samples), the Spearman rank correlation of the estimate's bin
/// means with the truth's bin means, per property: +1 when the estimates keep the truth's order
/// across the bins, -1 when they reverse it. NaN where the truth's bin means do not vary (a
/// property the family holds constant, e.g. a cohesionless soil's c), or the estimates' do not,
/// or the family has fewer than 3 bins.
struct Fig11Trend {
  int family = 0;  ///< soil::SoilFamily
  int bins = 0;    ///< bins with samples
  std::array<double, kSoilCount> rank_correlation{};
};

/// Spearman's rank correlation of a and b (same length): the Pearson correlation of their ranks,
/// ties given their mean rank. NaN when shorter than 3 or either has no spread (all ties).
double rankCorrelation(const std::vector<double>& a, const std::vector<double>& b);

/// The Fig11Trend of every family present in `bins`, in family order.
std::vector<Fig11Trend> fig11Trends(const std::vector<Fig11Bin>& bins);

struct SoilEvaluation {
  std::vector<SplitMetrics> splits;  ///< one per split present (test, held_out, validation, train)
  std::vector<Fig11Bin> fig11;       ///< over the test and held-out splits
  std::vector<Fig11Trend> fig11_trend;  ///< fig11Trends(fig11)
  /// mean_var_epistemic(held_out) / mean_var_epistemic(test), per property (NaN without both).
  std::array<double, kSoilCount> epistemic_ratio{};
};

/// The two skill statistics of SplitMetrics for one property: the MAE of `constant` against
/// `truth`, and the Pearson correlation of `estimate` with `truth` (same length; NaN when empty
/// or when either has no spread).
struct PropertySkill {
  double mae_constant = NAN, correlation = NAN;
};
PropertySkill propertySkill(const std::vector<double>& truth, const std::vector<double>& estimate, double constant);

/// Runs the estimator over every sample of `data` in batches. Single-threaded ATen.
SoilEvaluation evaluateEstimator(const SoilEstimator& est, const TrainingData& data);
std::string evaluationJson(const SoilEvaluation& e);
/// The decomposition's two markdown tables (ForceDecomposition), one row per split with rows.
std::string decompositionMarkdown(const SoilEvaluation& e);
/// Markdown tables (force error, the decomposition, errors in display units, calibration, epistemic ratio).
std::string evaluationMarkdown(const SoilEvaluation& e);
/// CSV of the Fig. 11 bins: family,id_bin,samples, then truth/mean/sigma per property.
std::string fig11Csv(const SoilEvaluation& e);
/// The Fig. 11 analogue as a picture: one panel per property (display units), x = I_d bin
/// centre, per soil family the estimate's bin mean with ±1σ bars (sqrt of the mean total
/// variance) and the truth's bin mean as a line; `caption` goes under the title.
/// 	hrows OutputError (font).
io::Image fig11Chart(const SoilEvaluation& e, const std::string& caption);

}  // namespace terramap::pinn

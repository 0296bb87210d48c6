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
/// (soil::fitPooledMultiStart, from the machine's previous fit and three fixed starts; with
/// `edge_preserving` the best of the windows before, centred on and after the sweep: fitWindow)
/// and published as this
/// sweep's SoilEstimateRecord, so soil_bayes, fee_index and octomap_strata read it as they read
/// soil_pinn's. With `lookahead_sweeps` k > 0 the window is centred: sweep s is fitted with the
/// rows of the sweeps before it and of the k after it, and published when sweep s + k has been
/// fitted rows (or at the end of the run), so the estimate fused into s's wedge describes the soil
/// around s rather than the ground the blade left behind (a causal window lags the soil by half its
/// length: on a 2 m strip crossed at 0.2 m a sweep, 10 sweeps lag it by about 1 m). The cost is
/// latency: the layer ahead of the blade receives its estimate k sweeps later.
/// Variances: the (residual-scaled) Gauss-Newton covariance's diagonal times `variance_inflation`
/// (a cell takes 1.4-2 estimates of overlapping windows, which soil_bayes fuses as independent),
/// as var_total, var_aleatoric and var_nullspace; no epistemic part.
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

/// The fit rows of one sample (stalled rows and rows without a cut left out): the mapped
/// geometry and cross-section, the blade's width, and the probability that the edge descended,
/// Φ(−v / gate_speed_sigma_mps) of the observed vertical speed v (a 0/1 step at sigma 0).
std::vector<soil::FitRow> fitRows(const soil::PinnSample& sample, double blade_width_m = 0.0,
                                  double gate_speed_sigma_mps = 0.0);
/// Horizon row p of the sample as a fit row, whatever its state (fitRows' rows are these).
soil::FitRow fitRow(const soil::PinnSample& sample, int p, double blade_width_m, double gate_speed_sigma_mps);

/// Which sweeps' rows each sweep's fit takes: the `window_sweeps - 1 - lookahead_sweeps` sweeps
/// before it, itself, and the `lookahead_sweeps` after it, of those whose blade ended within
/// `window_m` (m, map frame, horizontal) of its own. One machine's sweeps, in order. Plain
/// bookkeeping: no threads, no engine.
class SweepWindow {
 public:
  SweepWindow(int window_sweeps, int lookahead_sweeps, double window_m)
      : back_(window_sweeps - 1 - lookahead_sweeps), ahead_(lookahead_sweeps), reach_m_(window_m) {}
  /// Keeps `back` sweeps before each one and waits for `ahead` after it (rowsIn may take any
  /// range inside them).
  static SweepWindow keeping(int back, int ahead, double window_m) {
    SweepWindow w(back + ahead + 1, ahead, window_m);
    return w;
  }
  /// Appends a sweep's rows; returns its sequence number (0, 1, ...).
  long add(const Eigen::Vector3d& edge, std::vector<soil::FitRow> rows);
  /// True once every sweep sweep `seq`'s fit takes has been added.
  bool complete(long seq) const { return seq + ahead_ < next_; }
  /// The rows of sweep `seq`'s fit; `sweeps` receives how many sweeps they came from.
  std::vector<soil::FitRow> rowsFor(long seq, int* sweeps) const { return rowsIn(seq, -back_, ahead_, sweeps); }
  /// The rows of sweeps seq + from .. seq + to (within the kept range) whose blade ended within
  /// the reach of sweep seq's.
  std::vector<soil::FitRow> rowsIn(long seq, int from, int to, int* sweeps) const;
  /// Forgets the sweeps no fit from sweep `oldest_needed` on can take.
  void forgetBefore(long oldest_needed);
  long next() const { return next_; }

 private:
  struct Entry {
    long seq;
    Eigen::Vector3d edge;
    std::vector<soil::FitRow> rows;
  };
  std::deque<Entry> entries_;
  long next_ = 0;
  int back_, ahead_;
  double reach_m_;
};

/// A sweep's fit, from the window of its sweeps that fits it best.
struct WindowChoice {
  soil::PooledFit fit;
  int sweeps = 0;        ///< sweeps in the window
  std::size_t rows = 0;  ///< rows fitted (0: no window had min_rows)
  int chosen = -1;       ///< 0 centred, 1 the sweeps before and it, 2 it and the sweeps after, 3 / 4 as 1 / 2 with short_sweeps
  std::vector<soil::FitRow> fitted;  ///< the chosen window's rows
  int fits = 0;                      ///< fits run (windows with min_rows and rows of their own, times the starts)
};

/// Sweep `seq`'s fit (soil::fitPooledMultiStart from `starts`) with the window of
/// `window_sweeps` sweeps around it that holds `lookahead_sweeps` after it, and with
/// `edge_margin` > 0 also the windows that end and that start at it: the one whose soil explains
/// the sweep's own rows best is kept, a side one only if its cost on them is below edge_margin
/// times the centred one's (a Kuwahara filter: at a soil boundary the window on the sweep's side
/// holds one soil, the centred one a blend). `window` must keep window_sweeps - 1 sweeps each
/// side (SweepWindow::keeping) for the side windows. Pure. Threading: with an `executor` the
/// fits (each window from each start) run as its tasks; the result is the same for any thread
/// count and without one (serial).
WindowChoice fitWindow(const SweepWindow& window, long seq, int window_sweeps, int lookahead_sweeps, double edge_margin,
                       int min_rows, const std::vector<soil::SoilParamVector>& starts, const soil::PooledFitOptions& opt,
                       const Executor* executor = nullptr, int short_sweeps = 0);

/// Whether a fit's φ (rad, with its variance var_phi in rad²) is at an end of φ's range: closer
/// to it than sd_k of its standard deviations, and at least than 1 % of the range. The fit then
/// ran along the c–φ valley into the box's wall: its Gaussian puts a share of its mass outside
/// the physical range, so its curvature there says nothing of how far the valley reaches and the
/// estimate is no measurement (`phi_bound_invalid`). NaN var_phi counts as 0. Pure.
bool phiAtBound(double phi_rad, double var_phi, double sd_k);
/// True when φ's standard deviation sqrt(var_phi) (rad) exceeds k times that of a uniform belief
/// over φ's range, (hi - lo) / sqrt(12): the estimate tells less about φ than the range alone.
/// k <= 0: never.
bool phiUninformative(double var_phi, double k);

/// Whether the profile of the rows' cost along φ says the nearer end of φ's range is as good as
/// the fit (profile likelihood instead of the Gaussian's curvature, which a curved c–φ valley
/// misleads): the rows' cost (soil::rowsCost) with φ held at that end and the other properties
/// refitted, minus the fit's, at most sd_k² times the fit's residual_scale times
/// `variance_inflation` (the factors its published variance carries; ≤ 0 counts as 1): the end
/// lies inside the fit's sd_k-σ profile interval. One more fit of `rows`. Pure.
bool phiEndInsideProfile(const std::vector<soil::FitRow>& rows, const soil::PooledFit& fit, double sd_k,
                         double variance_inflation, const soil::PooledFitOptions& opt);

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
  /// A sweep whose estimate waits for the sweeps after it (lookahead_sweeps).
  struct Waiting {
    long seq = 0;
    SoilEstimateRecord record;   ///< everything but the fit
    soil::FitRow last_row;       ///< the geometry at the sweep's end, for β* and F_pred
    bool has_last_row = false;
  };
  struct MachineState {
    explicit MachineState(const SweepWindow& w) : window(w) {}
    SweepWindow window;
    std::deque<Waiting> waiting;
    soil::SoilParamVector last{};
    bool has_last = false;
  };
  void ingestSweep(ProcessContext& ctx, const SweepRecord& sweep);
  /// Publishes the waiting sweeps whose lookahead has arrived (all of them if `flush`).
  void publishReady(ProcessContext& ctx, MachineState& m, bool flush);
  void publish(ProcessContext& ctx, MachineState& m, Waiting& w);

  int horizon_ = 10, window_sweeps_ = 10, lookahead_sweeps_ = 5, min_rows_ = 10;
  double window_m_ = 2.0, gate_speed_sigma_mps_ = 0.05;
  /// Fit each sweep with the window before it, the centred one and the one after it, and keep
  /// the one whose rows the soil explains best (a Kuwahara filter): at a soil boundary the window
  /// on the sweep's own side holds one soil, the centred one two.
  bool edge_preserving_ = true;
  double edge_margin_ = 0.7;
  double variance_inflation_ = 1.5;
  bool phi_bound_invalid_ = true;
  double phi_uninformative_sd_ = 1.0;
  double phi_bound_sd_ = 1.0;
  bool phi_bound_profile_ = false;
  int short_window_sweeps_ = 5;
  soil::PooledFitOptions opt_;
  std::map<std::string, MachineState> machines_;
  soil::PendingSweeps pending_;
};

}  // namespace terramap::plugins

#pragma once
/// \file
/// Training the soil estimator (paper Eq. 8; ALGORITHMS.md §F), the library behind
/// `terramap train CONFIG`: a deep ensemble of PinnNet members, each trained with Adam on
/// mini-batches of 100 from the dataset's train split, early-stopped on the validation split's
/// loss, from its own seed (initial weights and batch order), on one intra-op thread so the
/// result is the same bits on any machine with the same libtorch.
///
/// Checkpoints: after every epoch each member's state (weights, Adam moments, epoch, best
/// weights so far, patience counter) is written atomically to CHECKPOINT_DIR/member_K.pt, tagged
/// with the training config hash; a rerun with the same config continues where it stopped, and
/// a finished member is not trained again.
#include "estimator.hpp"
#include "loss.hpp"

#include <terramap/eval/soil_dataset.hpp>

#include <functional>
#include <string>
#include <vector>

namespace terramap::pinn {

/// `terramap train CONFIG` reads it from YAML (configs/train/pinn.yaml documents each key).
struct TrainConfig {
  std::string dataset;                ///< dataset folder (terramap dataset --out)
  std::string out;                    ///< model file written at the end
  std::string checkpoint_dir;         ///< default: OUT + ".ckpt"
  int T = 30, P = 10;                 ///< history and horizon used (suffixes of the stored ones)
  std::vector<int> hidden{128, 128};
  int members = 5;
  std::int64_t seed = 1;
  int batch = 100;
  int max_epochs = 60;
  int patience = 8;                   ///< epochs without a better validation loss before stopping
  double learning_rate = 1e-3;
  /// Base failure angle of the physics layer (fee_torch.hpp; YAML `beta_base: min | nominal`).
  BetaBase beta_base = BetaBase::Min;
  /// Leave horizon rows where the machine stood stalled (soil::stalledRow) out of the force
  /// terms of the loss (YAML `mask_stalled`).
  bool mask_stalled = true;
  /// Cutting-edge thickness of the physics layer's penetration term (PinnConfig; YAML
  /// `edge_thickness_m`, m; 0 = no term).
  double edge_thickness_m = 0.0;
  /// Observation feature feeding the penetration gate directly (PinnConfig::gate_feature; YAML
  /// `gate_feature: NAME` of soil::obsFeatureNames(); -1 = none).
  int gate_feature = -1;
  /// The unit weight the dataset's sweeps computed Q with, for a surcharge weighed with the
  /// estimated gamma (PinnConfig::q_gamma_ref_n_m3; YAML `surcharge_gamma_ref_n_m3`; 0 = Q as
  /// extracted).
  double q_gamma_ref_n_m3 = 0.0;
  /// The penetration gate read from gate_feature's sign instead of learned (PinnConfig::
  /// gate_observed; YAML `gate: observed | learned`).
  bool gate_observed = false;
  /// theta_k's depth and width from the cut's cross-section (PinnConfig::sliced_geometry; YAML
  /// `geometry: sliced | mean`). Needs a dataset with the `profile` array.
  bool sliced_geometry = false;
  LossWeights weights;
};

/// The hash that tags checkpoints: every field that changes the trained weights.
std::string trainConfigHash(const TrainConfig& cfg);

/// The dataset as tensors for one (T, P): samples with a finite force at every horizon step.
struct TrainingData {
  at::Tensor obs_raw;    ///< [N, T, D] float32 (raw features)
  at::Tensor theta_k;    ///< [N, P, 6] float32
  at::Tensor force;      ///< [N, P, 2] float32
  at::Tensor moving;     ///< [N, P] bool: the horizon row is not stalled (soil::stalledRow)
  at::Tensor truth;      ///< [N, 5] float32 (evaluation only)
  at::Tensor truth_geometry;  ///< [N, 5] float32 simulator's alpha, rho, d, w, q (diagnosis only; NaN if unknown)
  at::Tensor force_quiet;     ///< [N, P, 2] float32 the force without its noise (evaluation only; NaN if unknown)
  /// Per horizon row, diagnosis only (eval::SoilDataset; NaN if unknown): the simulator's FEE
  /// geometry [N, P, 5], force_quiet's parts [N, P, 3, 2] (FEE, inertia, penetration), the
  /// edge's true vertical speed [N, P].
  at::Tensor truth_geometry_rows, force_parts, edge_vz;
  std::vector<std::uint8_t> split, family;
  std::vector<float> relative_density;
  long dropped_nonfinite = 0;  ///< samples without a finite force (no sensor, NaN features)
  long size() const { return obs_raw.defined() ? obs_raw.size(0) : 0; }
  /// Row indices of one split.
  std::vector<long> indices(eval::DatasetSplit s) const;
};
/// \throws InputError if T or P exceed what the dataset stored.
/// `sliced`: theta_k's d and w from the dataset's profile (soil::applySlicedGeometry), as a
/// model with PinnConfig::sliced_geometry expects; the simulator's rows (truth_geometry_rows)
/// get the same from truth_profile_rows where the dataset has them.
/// \throws InputError when `sliced` and the dataset has no finite profile.
TrainingData makeTrainingData(const eval::SoilDataset& d, int T, int P, bool sliced = false);

struct MemberReport {
  int epochs = 0, best_epoch = 0;
  double best_validation_loss = 0, final_train_loss = 0;
  bool resumed = false;
};
struct TrainReport {
  std::vector<MemberReport> members;
  long train_samples = 0, validation_samples = 0;
  double wall_s = 0;
};

/// Trains the ensemble and writes cfg.out. `on_progress(member, epoch, train_loss, val_loss,
/// val_force_wmae_N)` after every epoch. \throws InputError (dataset), OutputError (model,
/// checkpoints).
TrainReport trainEnsemble(const TrainConfig& cfg,
                          const std::function<void(int, int, double, double, double)>& on_progress = {});

}  // namespace terramap::pinn

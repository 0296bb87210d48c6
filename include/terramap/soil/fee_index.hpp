#pragma once
/// \file
/// The FEE index (ALGORITHMS.md §I): "the force needed to cut here", the FEE of a reference cut
/// that is the same everywhere, so a map of it compares soils and not terrain. What the
/// `fee_index` plugin writes per cell, and what `terramap eval-soil-map` computes for the truth
/// soil. Pure functions: safe from any thread; nothing throws (an invalid FEE is reported in
/// FeeIndexValue::validity).
///
/// Index (N): |F| (Eq. 1's f, the blade's normal plus friction reaction) or, with `horizontal`,
/// F_x (the push along travel), at β* minimising N_γ (`beta_min`) or Rankine's π/4 − φ/2.
/// Variance (N²): J Σ Jᵀ with Σ = diag of the soil variances and J the gradient of the index in
/// [c, φ, γ, c_a, δ] from fee::jacobianF with β's dependence on φ and δ chained in
/// (fee::betaMinGradient, or −½ on φ for the nominal angle).
#include <terramap/soil/fee.hpp>

#include <limits>

namespace terramap::soil {

struct FeeIndexConfig {
  /// The reference cut: α = 0, ρ = 80°, d = 0.2 m, w = 1.85 m, Q = 0 (the authors' code).
  fee::Geometry geometry{0.0, 80.0 * 3.14159265358979323846 / 180.0, 0.2, 1.85, 0.0};
  bool beta_min = true;     ///< β* (true) or Rankine's nominal angle
  bool horizontal = false;  ///< F_x instead of |F|
};

/// The index and its variance for one soil belief; NaN (and a validity other than Valid) where
/// the FEE has no valid solution for that soil and cut.
struct FeeIndexValue {
  double index_n = std::numeric_limits<double>::quiet_NaN();
  double var_n2 = std::numeric_limits<double>::quiet_NaN();
  fee::Validity validity = fee::Validity::NotFinite;
};

/// The index of the soil `mean` with its variance from the per-parameter variances `var`
/// (fee::Soil's fields, squared units; zeros give the index alone).
FeeIndexValue feeIndexOf(const fee::Soil& mean, const fee::Soil& var, const FeeIndexConfig& cfg);

}  // namespace terramap::soil

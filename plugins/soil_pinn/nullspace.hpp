#pragma once
/// \file
/// Nullspace inflation of the estimated soil variances at inference (paper Eq. 7,
/// ALGORITHMS.md §F). Where the horizon's stacked Jacobian J [2P x 5] cannot see a direction
/// of the soil parameters, the force carries no information about it, so the network's
/// variance there is unsupervised and may be overconfident. Eq. 7 projects a fixed
/// "ambiguity" covariance Sigma_a onto the null space of J:
///   Sigma_n = (I - J^+ J) Sigma_a,
/// where J^+ is a truncated pseudo-inverse: singular values s <= max(a_tol, r_tol * s_max)
/// are treated as zero (so J^+ J = V_k V_k^T over the kept right singular vectors).
/// The result is combined with the network's variances by the elementwise MAXIMUM of the
/// diagonals: the paper writes min, which would shrink a variance the projection says is
/// unknown; its stated intent is to inflate (ALGORITHMS.md §F).
/// Units: J in N per parameter unit (SoilCol order), variances in parameter units squared.
/// Note a_tol = 1500 compares singular values of columns with mixed units (N/Pa vs N/rad),
/// exactly as the paper does; the tolerances are its values. Consequence in SI units: for a
/// typical cut (d 0.15 m, w 1.8 m) the c, ca and gamma columns are about 1.3 N/Pa, 0.3 N/Pa and
/// 0.08 N/(N/m^3), far below 1500, while phi and delta are ~5e4 N/rad; so c, ca and gamma
/// always land in the "null space" and always take the ambiguity variance. Scaling the
/// columns (e.g. by each parameter's range) before the SVD would change that; not done here.
/// All in float64; batched over any leading dimensions. Threading: ATen ops only.
/// Shapes other than documented throw std::invalid_argument (or c10::Error from ATen).
#include <ATen/ATen.h>

namespace terramap::pinn {

struct NullspaceTolerances {
  double a_tol = 1500.0;  ///< absolute singular-value threshold (paper)
  double r_tol = 0.05;    ///< relative to the largest singular value (paper)
};

/// I - J^+ J for J [..., m, n] -> [..., n, n] float64 (the projector onto J's numerical null space).
at::Tensor nullspaceProjector(const at::Tensor& J, const NullspaceTolerances& tol = {});

/// Eq. 7: Sigma_n = (I - J^+ J) Sigma_a. J [..., m, 5]; sigma_a [5,5] or its diagonal [5]
/// (broadcast over the batch). Returns [..., 5, 5] float64.
at::Tensor nullspaceCovariance(const at::Tensor& J, const at::Tensor& sigma_a, const NullspaceTolerances& tol = {});

/// Combined variances: max(var_theta, diag(Sigma_n)) elementwise. var_theta [..., 5] (e.g.
/// exp of the network's log-variances), sigma_n [..., 5, 5]. Returns [..., 5] float64.
at::Tensor inflateVariances(const at::Tensor& var_theta, const at::Tensor& sigma_n);

/// Stacks a per-step Jacobian [B,P,2,K] over the horizon into [B,2P,K] (rows Fx_0, Fz_0, Fx_1, ...).
at::Tensor stackHorizon(const at::Tensor& J_steps);

/// The inference path in one call: the network's soil variances exp(S) inflated by Eq. 7 over
/// the horizon. J_steps [B,P,2,K >= 5] (PinnOutput::J: its first five columns are the soil
/// parameters; steps where the FEE is invalid have zero rows and so add no information),
/// log_var [B, K' >= 5] (PinnOutput::log_var), sigma_a [5] or [5,5]. Returns [B,5] float64
/// variances in SoilCol units squared.
at::Tensor soilVariances(const at::Tensor& J_steps, const at::Tensor& log_var, const at::Tensor& sigma_a,
                         const NullspaceTolerances& tol = {});

/// A default ambiguity covariance (the paper does not publish its value): diagonal, each
/// parameter's variance of a uniform distribution over its squashing range (model.hpp's
/// kSoilRanges), (hi - lo)^2 / 12 -- "nothing known but the range". [5] float64.
at::Tensor defaultAmbiguityVariance();

}  // namespace terramap::pinn

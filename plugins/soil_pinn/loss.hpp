#pragma once
/// \file
/// The PINN training loss (paper Eq. 8, ALGORITHMS.md §F). With m[b,p] the FEE validity of
/// sample b at horizon step p and N = B P, each term is a mean over the batch AND the horizon:
///  - force_mae  = 1/N sum m (w_x |F_x - F^_x| + w_z |F_z - F^_z|)                         [N]
///  - nll        = 1/N sum m 1/2 [r^T Sigma^-1 r + ln det Sigma]   (Eq. 3), r = F - F^ with F^
///                 detached and Sigma = Sigma_F + sigma_floor I (Sigma_F's Jacobian is already
///                 detached), so its gradient reaches the log-variances S only          [1]
///  - dngamma    = 1/N sum m |dN_gamma/dbeta|  (gradient into beta_res only, model.hpp)      [1]
///  - range      = 1/N sum m sum_theta [ReLU((theta - hi)/span) + ReLU((lo - theta)/span)] over
///                 theta_u (kSoilRanges), d_res, beta_res (their bounds), and
///                 ReLU(S - S_hi) + ReLU(S_lo - S) over the seven log-variances
///                 (model.hpp logVarLo/Hi)                                               [1]
///  - residual   = 1/N sum m (d_res^2 + beta_res^2)  (MSE towards 0 of each residual)   [m^2, rad^2]
///  - force_res  = 1/B sum_b (w_x |F^r_x| + w_z |F^r_z|)  (every sample)                 [N]
///  - prior      = 1/B sum_b sum_theta ((theta - mid)/span)^2 over theta_u (every sample): a weak
///                 Gaussian prior at the middle of each physical range, which decides the
///                 directions the force does not (the FEE's null space: gamma, c vs c_a)    [1]
///  - soil       = 1/B sum_b sum_theta ((theta - theta_true)/span)^2 over theta_u, for the samples
///                 whose truth soil is given (pinnLoss's `truth`; 0 without): supervision by the
///                 simulator's truth, beyond the paper (whose loss sees only forces). The force
///                 alone leaves the c-phi-delta-gamma trade-off of the FEE to the initialisation
///                 (docs/soil_estimator.md "Skill"); a network trained in simulation knows the
///                 truth and may use it. Its gradient reaches theta_u only                  [1]
/// A per-sample quantity (range, residual) counts once per valid step, so a sample whose
/// steps are all invalid (eta, beta or rho out of limits, d + d_res <= 0) contributes only its
/// F^r term, and one partly valid counts in proportion. Invalid entries are replaced by
/// finite stand-ins before any division, so they give exact zero gradients (never NaN).
/// The terms are returned unweighted; total = sum of lambda * term.
/// All float64 scalars. Threading: ATen ops only.
#include "model.hpp"

#include <array>

namespace terramap::pinn {

/// Loss weights. The paper does not publish its lambdas; these defaults make every weighted
/// term O(0.1-1) for cuts of a few kN with a 10 % parameter spread:
///  lambda_F 1e-3 /N (force_mae in kN), lambda_NLL 0.01 (NLL ~ 15-25 for 100-N force
///  deviations), lambda_beta 0.1, lambda_range 1 (penalties are in spans, so any violation is
///  noticed), lambda_res 10 (d_res^2 <= 0.0025 m^2, beta_res^2 <= 0.04 rad^2: residuals are
///  allowed but cost), lambda_Fr 2e-4 /N (F^r five times cheaper than force error: it may
///  absorb a systematic model mismatch over the horizon, not replace the FEE).
struct LossWeights {
  double lambda_F = 1e-3;
  double lambda_NLL = 0.01;
  double lambda_beta = 0.1;
  double lambda_range = 1.0;
  double lambda_res = 10.0;
  double lambda_Fr = 2e-4;
  double lambda_prior = 0.0;  ///< 0 = no prior term (the paper has none)
  double lambda_soil = 0.0;   ///< 0 = no supervision by the truth soil (the paper has none)
  std::array<double, 2> w_xz{1.0, 0.5};  ///< paper's x/z weights of both wMAE terms
  /// N^2 added to Sigma_F's diagonal inside the NLL: a 1 N floor (far below force-sensor noise)
  /// that keeps Sigma invertible where J is rank-deficient.
  double sigma_floor_n2 = 1.0;
};

/// Each term unweighted (see the file comment) and the weighted total; float64 scalars.
struct LossTerms {
  at::Tensor force_mae, nll, dngamma, range, residual, force_res, prior, soil;
  at::Tensor total;
};

/// force: measured force of the blade on the soil [B,P,2] (N, [x along travel, z up]).
/// row_mask: optional [B,P] bool; a false row is left out of every term as an invalid FEE step
/// is (the trainer masks rows where the machine stood stalled: its measured force is not the
/// soil's failure force), so m above is validity AND row_mask.
/// truth: optional [B,5] truth soil (SI, SoilCol order) for the soil term; without it the term is 0.
/// \throws std::invalid_argument if force is not [B,P,2] matching out.F, row_mask not [B,P] or
/// truth not [B,5].
LossTerms pinnLoss(const PinnOutput& out, const at::Tensor& force, const LossWeights& w = {},
                   const at::Tensor& row_mask = {}, const at::Tensor& truth = {});

}  // namespace terramap::pinn

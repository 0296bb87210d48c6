#pragma once
/// \file
/// The paper's FEE force F (not F_total; see terramap/soil/fee.hpp) as a differentiable torch
/// layer for the PINN (ALGORITHMS.md §E, §F; paper Eq. 1, 2, 9). Same formulas and validity
/// rules as terramap::fee, evaluated element-wise over a batch B and a horizon P.
///
/// Precision: every input is cast to float64 and all physics runs in float64; the outputs are
/// cast back to the dtype of `soil` (pass float64 soil to keep float64 end to end).
/// Invalid entries: where a validity rule fails, the formulas are evaluated at a fixed
/// admissible stand-in configuration instead (the "double where" trick), and F, the factors
/// and dN_gamma/dbeta are set to 0 there. So nothing is NaN or infinite, and the gradient of
/// any masked loss w.r.t. the inputs of an invalid entry is exactly 0 (a NaN from a pole
/// would otherwise leak through where()'s backward as 0 * inf).
/// Threading: plain ATen ops; the caller sets at::set_num_threads (1 inside engine tasks).
/// Throws c10::Error (from ATen) or std::invalid_argument on inconsistent shapes.
#include <terramap/soil/soil_parameters.hpp>

#include <ATen/ATen.h>

#include <string>

namespace terramap::pinn {

/// Columns of the soil tensor, everywhere in soil_pinn: soil::SoilParam's order.
enum SoilCol : int {
  kSoilC = soil::kParamC,
  kSoilPhi = soil::kParamPhi,
  kSoilCa = soil::kParamCa,
  kSoilDelta = soil::kParamDelta,
  kSoilGamma = soil::kParamGamma,
  kSoilCount = soil::kSoilParamCount
};

/// Output of feeForward(). Shapes with B the batch, P the horizon; dtype of `soil` unless noted.
struct FeeOut {
  at::Tensor F;              ///< [B,P,2] N, paper's F = f [sin(rho+delta-alpha), cos(..)]; 0 where invalid
  at::Tensor valid;          ///< [B,P] bool, true where fee::check() would return Valid
  at::Tensor N_gamma, N_c, N_Q, N_ca;  ///< [B,P] dimensionless N-factors; 0 where invalid
  at::Tensor eta;            ///< [B,P] rad, delta + rho + phi + beta (computed everywhere)
  at::Tensor beta;           ///< [B,P] rad, the failure angle used (broadcast input)
};

/// Evaluates the FEE. soil [B,5] in SoilCol order (Pa, rad, Pa, rad, N/m^3); rho, alpha (rad),
/// w, d (m), q (N) [B,P]; beta (rad) [B] or [B,P]. Differentiable w.r.t. every input (autograd).
FeeOut feeForward(const at::Tensor& soil, const at::Tensor& rho, const at::Tensor& alpha, const at::Tensor& w,
                  const at::Tensor& d, const at::Tensor& q, const at::Tensor& beta);

/// Nominal (Rankine) failure angle pi/4 - phi/2 (paper Eq. 9), element-wise, same dtype.
at::Tensor betaNominal(const at::Tensor& phi);

/// The failure angle beta* minimising N_gamma (fee::betaMin, ALGORITHMS.md §E) element-wise over
/// broadcastable float64 angle tensors (rad), differentiable w.r.t. every angle (the closed
/// form: 2 beta = atan2(b, a) + acos(sin(delta - alpha) / hypot(a, b)), the admissible root with
/// the smallest N_gamma). `found` (bool, same shape) is false where fee::betaMin() is NaN (no
/// admissible minimum, angles outside their ranges, the flat case aside) or where the acos is
/// within 1e-9 of its poles (its derivative is infinite there); those entries return
/// `fallback` (e.g. betaNominal(phi)) with the gradient of `fallback`, so nothing is NaN.
struct BetaMinOut {
  at::Tensor beta;   ///< rad
  at::Tensor found;  ///< bool
};
BetaMinOut betaMinTorch(const at::Tensor& phi, const at::Tensor& delta, const at::Tensor& alpha,
                        const at::Tensor& rho, const at::Tensor& fallback);

/// Which failure angle the physics layer starts from (the network adds beta_res to it).
///  - Nominal: Rankine's pi/4 - phi/2 (paper Eq. 9), the paper's choice.
///  - Min: beta* of betaMinTorch() per horizon step (Rankine where no admissible minimum
///    exists), the angle the simulator's wedge fails at. Rankine's angle makes the same cut
///    roughly twice as hard in the simulator's soils (docs/soil_estimator.md), more than
///    beta_res can bridge.
enum class BetaBase { Nominal, Min };
/// "nominal" / "min".
const char* betaBaseName(BetaBase b);
/// \throws std::invalid_argument naming the value on anything but "nominal" or "min".
BetaBase parseBetaBase(const std::string& s);
/// The base failure angle [B,P] (rad, float64) for soil angles phi, delta [B] or [B,P] and
/// horizon angles alpha, rho [B,P]. Differentiable.
at::Tensor failureAngle(BetaBase base, const at::Tensor& phi, const at::Tensor& delta, const at::Tensor& alpha,
                        const at::Tensor& rho);

/// Analytic dN_gamma/dbeta (the formula of fee::dNgammaDbeta), element-wise over broadcastable
/// tensors of angles in rad. No masking: infinite/NaN at the poles (beta, rho, eta = 0 or pi);
/// mask the inputs first (where(valid, x, stand-in)) when it feeds a loss.
at::Tensor dNgammaDbeta(const at::Tensor& phi, const at::Tensor& delta, const at::Tensor& alpha,
                        const at::Tensor& rho, const at::Tensor& beta);

/// The validity rules of fee::check() (NotFinite and every range rule), element-wise:
/// true where all hold. Inputs as for feeForward() with beta already broadcast to [B,P].
at::Tensor feeValid(const at::Tensor& soil, const at::Tensor& rho, const at::Tensor& alpha, const at::Tensor& w,
                    const at::Tensor& d, const at::Tensor& q, const at::Tensor& beta);

/// Columns of feeJacobian(): the soil parameters, then depth and failure angle.
enum JacCol : int { kJacC = 0, kJacPhi, kJacCa, kJacDelta, kJacGamma, kJacD, kJacBeta, kJacCount };

/// dF/d[c, phi, ca, delta, gamma, d, beta] per entry, beta held independent (as
/// fee::jacobianF): [B,P,2,7] float64, rows [Fx, Fz], N per parameter unit. Computed by
/// autograd on detached copies of the inputs, so the result carries no graph (the NLL needs it
/// detached anyway) and works under torch::NoGradGuard. 0 where invalid.
at::Tensor feeJacobian(const at::Tensor& soil, const at::Tensor& rho, const at::Tensor& alpha, const at::Tensor& w,
                       const at::Tensor& d, const at::Tensor& q, const at::Tensor& beta);

/// feeJacobian() with beta = failureAngle(base, phi, delta, alpha, rho) + beta_res (beta_res
/// [B]): the phi and delta columns are total derivatives (beta's dependence on them chained
/// in), column kJacBeta is dF/dbeta_res. [B,P,2,7] float64, detached; 0 where invalid.
at::Tensor feeJacobianChained(const at::Tensor& soil, const at::Tensor& rho, const at::Tensor& alpha,
                              const at::Tensor& w, const at::Tensor& d, const at::Tensor& q,
                              const at::Tensor& beta_res, BetaBase base);

/// The physics layer's penetration term (PinnConfig::edge_thickness_m; fee::penetrationForce):
/// Fz = -gate (c N_c(phi) + gamma d N_q(phi)) t_e w, the blade's force on the soil while the
/// edge descends with probability `gate`. soil [B,5] float64 (SoilCol), w, d, gate [B,P]
/// float64. `J` [B,P,2,7] float64, detached, LogVarCol columns: the z row's derivatives in c,
/// phi, gamma and d (through d_res), the gate held fixed (it is not a soil parameter, as F^r).
struct PenetrationOut {
  at::Tensor Fz;  ///< [B,P] N, differentiable w.r.t. soil, d and gate
  at::Tensor J;   ///< [B,P,2,7]
};
PenetrationOut penetrationForward(const at::Tensor& soil, const at::Tensor& w, const at::Tensor& d,
                                  const at::Tensor& gate, double edge_m);

}  // namespace terramap::pinn

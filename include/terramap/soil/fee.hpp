#pragma once
/// \file
/// The fundamental equation of earthmoving (FEE), paper Eq. 1, 2, 9; ALGORITHMS.md §E.
/// Pure functions, no torch, no state, no allocation: safe to call from any thread at once.
/// Nothing here throws: a bad input is reported through `Validity`, never by exception,
/// because the estimator evaluates the FEE inside training loops where an invalid sample is
/// an ordinary event (it masks the loss) rather than an error.
///
/// Units: Pa, rad, N/m^3, m, N. Frame of the force: x along the direction of travel
/// (horizontal), z up; the force is that of the blade on the soil (the soil pushes the blade
/// with the opposite force).
///
/// Symbols: c cohesion, phi internal friction angle, gamma unit weight, ca adhesion,
/// delta soil-tool friction angle, alpha surface slope (positive = terrain rises ahead of the
/// blade), rho rake angle (blade to horizontal, measured through the soil), d cutting depth,
/// w blade width in contact, Q surcharge weight, beta failure-plane angle.
///
/// Geometry convention (the one under which the paper's N-factors are exact; re-derived from
/// the force balance of the soil wedge): rho and beta are measured from the soil *surface*
/// line (which rises at alpha ahead of the blade), not from the horizontal, and d is the
/// depth of the cutting edge measured normal to the surface. rho < pi/2 means the top of the
/// blade leans back over the edge, so the wedge lies above the blade face. With that, the
/// wedge is the triangle (edge, blade top, failure-plane exit) of area d^2 (cot rho + cot beta)/2,
/// gravity makes the angle alpha with the surface normal, and rotating the blade reaction
/// back to the world frame gives the paper's direction [sin(rho+delta-alpha), cos(rho+delta-alpha)].
/// On level ground (alpha = 0) every angle is simply measured from the horizontal. The paper's
/// own wedge length x_max = d / (cos alpha (tan(alpha+beta) - tan alpha)) (Alg. 4) and the
/// extraction rule rho = alpha + blade angle from horizontal (ALGORITHMS.md §C) use the same
/// convention; tests/unit/fee checks it against Coulomb's passive pressure on sloping backfill.
///
/// Which force to use:
///  - The soil estimator (PINN, Bayesian layers, fee_index) uses the paper's F: it is what the
///    paper's network was trained against, and the estimator's residual force absorbs the rest.
///  - The simulator uses F_total = F + adhesion along the blade face, with beta = beta*, because
///    it is the ground truth and must be the complete force of the wedge model.
#include <Eigen/Core>
#include <cmath>
#include <string>

namespace terramap::fee {

/// Soil parameters (the unknowns the estimator infers).
struct Soil {
  double c_pa = 0;         ///< cohesion
  double phi_rad = 0;      ///< internal friction angle
  double gamma_n_m3 = 0;   ///< unit weight
  double ca_pa = 0;        ///< adhesion
  double delta_rad = 0;    ///< soil-tool friction angle
};

/// Tool/terrain geometry (what blade_sweep extracts).
struct Geometry {
  double alpha_rad = 0;  ///< surface slope
  double rho_rad = 0;    ///< rake angle
  double d_m = 0;        ///< cutting depth
  double w_m = 0;        ///< width
  double q_n = 0;        ///< surcharge weight
};

/// The N-factors (dimensionless) and eta = delta + rho + phi + beta.
/// N_gamma = (cot rho + cot beta) sin(alpha+phi+beta) / (2 sin eta)
/// N_c     = cos phi / (sin beta sin eta)
/// N_Q     = sin(alpha+phi+beta) / sin eta
/// N_ca    = -cos(rho+phi+beta) / (sin rho sin eta)
struct Factors {
  double eta_rad = 0, N_gamma = 0, N_c = 0, N_Q = 0, N_ca = 0;
};

/// Which validity rule failed, or Valid. Rules are checked in the order of this enum except
/// NotFinite, which is checked first (a NaN would otherwise be misreported as a range rule).
/// NoAdmissibleBeta is only produced by evaluateAtBetaMin().
enum class Validity {
  Valid, DepthNotPositive, WidthNotPositive, NegativeCohesion, NegativeAdhesion,
  NegativeUnitWeight, NegativeSurcharge, PhiOutOfRange, DeltaOutOfRange, AlphaOutOfRange,
  RhoOutOfRange, BetaOutOfRange, RhoPlusBetaTooLarge, EtaOutOfRange, AlphaPhiBetaOutOfRange,
  NotFinite, NoAdmissibleBeta
};
/// Human-readable rule, e.g. "0 < beta < pi/2" ("valid" for Valid). Static storage.
const char* validityRule(Validity v);
/// The enumerator's name, e.g. "BetaOutOfRange" (for logs and JSON). Static storage.
const char* validityName(Validity v);

/// One FEE evaluation. Forces in N in the world frame (x along travel, z up), blade on soil.
struct Result {
  double beta_rad = 0;                    ///< failure angle used (NaN if beta* did not exist)
  Factors n;                              ///< N-factors at beta_rad
  /// Eq. 1: magnitude of the blade's normal + friction reaction, which acts at delta from the
  /// blade normal. Coulomb's passive force P_p = 1/2 gamma H^2 K_p is this quantity, not Fx.
  double f_N = 0;
  Eigen::Vector2d F_N = Eigen::Vector2d::Zero();        ///< paper's F = f [sin(rho+delta-alpha), cos(...)]
  /// F + (ca d w / sin rho) [cos(rho-alpha), -sin(rho-alpha)]: the adhesion along the blade face
  /// that the paper's F omits (the N_ca term only accounts for its effect on the wedge balance).
  Eigen::Vector2d F_total_N = Eigen::Vector2d::Zero();
  Validity validity = Validity::Valid;
  bool valid() const { return validity == Validity::Valid; }
};

/// Nominal (Rankine) failure angle beta = pi/4 - phi/2 (paper Eq. 9). The estimator adds a
/// learned residual to it. NaN if phi is not finite.
double betaNominal(const Soil& s);

/// Failure angle beta* minimising N_gamma (closed form, ALGORITHMS.md §E):
/// with K1 = sin(delta+rho-alpha), K2 = sin rho, E = alpha+delta+rho+2 phi,
/// a = K1 cos rho - K2 cos E, b = -K1 sin rho + K2 sin E, the stationary points of N_gamma are
/// 2 beta = atan2(b, a) +- acos(sin(delta-alpha) / sqrt(a^2+b^2)) (+ 2 pi k).
/// A root is admissible when it satisfies every beta-dependent validity rule
/// (0 < beta < pi/2, rho+beta < pi, 0 < eta < pi, 0 < alpha+phi+beta < pi); of the admissible
/// roots the one with the smaller N_gamma is returned. Only local minima are candidates (the
/// "+" branch; the "-" branch is a maximum): they coincide with "smaller N_gamma" whenever
/// alpha + phi >= 0, and when the ground falls away faster than phi (alpha + phi < 0) the
/// only admissible stationary point can be a maximum, which must not be returned as a minimum.
/// When N_gamma does not depend on beta at all (a = b = sin(delta-alpha) = 0, e.g. phi = 0
/// against a smooth vertical blade on level ground), every beta is a minimiser and the
/// nominal pi/4 - phi/2 is returned.
/// Depends only on phi, delta, alpha, rho (not on c, gamma, ca, d, w, Q).
/// NaN when no admissible minimum exists, when those angles are non-finite or outside their
/// own validity ranges, or when N_gamma decreases all the way to the edge of the admissible
/// interval (then the minimum is a boundary, not a failure plane).
double betaMin(const Soil& s, const Geometry& g);

/// d beta*/d phi and d beta*/d delta (rad/rad) of betaMin(), differentiating its closed form
/// (the admissible root it returns: 2 beta* = atan2(b, a) + acos(sin(delta - alpha) / R) + 2 pi k,
/// so k drops out). {NaN, NaN} where betaMin() is NaN, in the flat case (returns Rankine's
/// angle there: {-0.5, 0}) is handled as betaMin() handles it.
Eigen::Vector2d betaMinGradient(const Soil& s, const Geometry& g);

/// Checks every validity rule for (soil, geometry, beta); returns the first that fails.
Validity check(const Soil& s, const Geometry& g, double beta_rad);
/// The N-factors at beta. Computed even when invalid (may be infinite or NaN there).
Factors factors(const Soil& s, const Geometry& g, double beta_rad);
/// Full evaluation at a given beta. Never throws; an invalid input is reported in `validity`
/// and the numbers are still computed where finite.
Result evaluate(const Soil& s, const Geometry& g, double beta_rad);
/// evaluate() with the N-factors given: `n` must be factors(s, g, beta_rad), which depend only
/// on φ, δ, α, ρ and β. A fit that varies c, c_a, γ, d, w or Q at fixed angles reuses them
/// (the result is bit for bit evaluate()'s).
Result evaluateWith(const Soil& s, const Geometry& g, double beta_rad, const Factors& n);
/// evaluate() at betaNominal(s).
Result evaluateAtBetaNominal(const Soil& s, const Geometry& g);
/// evaluate() at betaMin(s, g). If the other rules hold but no admissible beta* exists,
/// validity is NoAdmissibleBeta and beta_rad and all forces are NaN.
Result evaluateAtBetaMin(const Soil& s, const Geometry& g);

/// The one wedge whose FEE equals the FEE summed over the slices across the blade of a cut whose
/// cross-section holds Σ d ds = `area_m2` (m²) and Σ d² ds = `depth2_m3` (m³): the FEE is linear
/// in both for one α and ρ, so depth depth2 / area and width area² / depth2 (m). Returns false and
/// leaves d_m, w_m as they are unless both sums are finite and > 0. Pure; never throws.
inline bool slicedWedge(double area_m2, double depth2_m3, double& d_m, double& w_m) {
  // NaN fails both comparisons; an infinity passes them and is refused by the finiteness test.
  if (!(area_m2 > 0 && depth2_m3 > 0) || !std::isfinite(area_m2) || !std::isfinite(depth2_m3)) return false;
  d_m = depth2_m3 / area_m2;
  w_m = area_m2 * area_m2 / depth2_m3;
  return true;
}

/// dN_gamma/dbeta at beta (zero at beta*; the paper's loss drives it to zero, Eq. 8).
double dNgammaDbeta(const Soil& s, const Geometry& g, double beta_rad);

/// Parameter vector order for Jacobians: [c, phi, gamma, ca, delta, alpha, rho, d, w, Q, beta].
constexpr int kParamCount = 11;
/// Indices into the parameter vector, in the order above.
enum Param : int { kC = 0, kPhi, kGamma, kCa, kDelta, kAlpha, kRho, kD, kW, kQ, kBeta };
using Jacobian = Eigen::Matrix<double, 2, kParamCount>;
using ParamVector = Eigen::Matrix<double, kParamCount, 1>;
/// Packs (soil, geometry, beta) in the Jacobian's parameter order.
ParamVector pack(const Soil& s, const Geometry& g, double beta_rad);
/// Inverse of pack().
void unpack(const ParamVector& p, Soil& s, Geometry& g, double& beta_rad);

/// Analytic dF/dTheta of the paper's F (not F_total), beta held as an independent parameter.
/// Rows: [Fx, Fz]; columns: parameter order above; units N per parameter unit (N/rad for
/// angles). Derived by hand (no finite differences); meaningful where check() is Valid, and
/// computed by the same formulas elsewhere (may be infinite/NaN at the singular edges).
/// For uncertainty propagation Sigma_F = J Sigma_Theta J^T (paper Eq. 5).
Jacobian jacobianF(const Soil& s, const Geometry& g, double beta_rad);
/// When beta is not independent but beta = betaNominal(s) (+ a residual), chain it in with
/// J.col(kPhi) += -0.5 * J.col(kBeta).
/// Analytic dF_total/dTheta (same conventions as jacobianF).
Jacobian jacobianFTotal(const Soil& s, const Geometry& g, double beta_rad);

/// Terzaghi/Prandtl strip bearing-capacity factors at phi (rad) and their derivatives
/// (per rad): N_q = e^{pi tan phi} tan^2(pi/4 + phi/2), N_c = (N_q - 1) / tan phi
/// (Prandtl's pi + 2 as phi -> 0, where the derivatives are those of the limit's series).
struct BearingFactors {
  double N_c = 0, N_q = 0, dN_c = 0, dN_q = 0;
};
BearingFactors bearingFactors(double phi_rad);

/// Vertical resistance of the soil to a descending cutting edge of thickness `edge_m` (m) over
/// width w_m at depth d_m: q_b t_e w with q_b = c N_c + gamma d N_q (N, >= 0 for valid soil;
/// the soil pushes the edge up, so the blade's force on the soil gains -this in z), and its
/// derivatives d/d[c, phi, gamma, d] (N per Pa, rad, N/m^3, m), from one evaluation of the
/// bearing factors. The simulator's truth force adds it while the edge descends (docs/sim.md,
/// "Model"); the estimator's physics layer adds it weighted by the probability that the edge
/// descended.
struct Penetration {
  double force_n = 0;
  Eigen::Vector4d gradient = Eigen::Vector4d::Zero();
};
Penetration penetration(const Soil& s, double d_m, double w_m, double edge_m);
/// penetration() with the bearing factors given: `b` must be bearingFactors(s.phi_rad).
Penetration penetrationWith(const Soil& s, double d_m, double w_m, double edge_m, const BearingFactors& b);
/// penetration(...).force_n.
inline double penetrationForce(const Soil& s, double d_m, double w_m, double edge_m) {
  return penetration(s, d_m, w_m, edge_m).force_n;
}

}  // namespace terramap::fee

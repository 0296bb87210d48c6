#pragma once
/// \file
/// The fundamental equation of earthmoving (FEE), paper Eq. 1, 2, 9; ALGORITHMS.md §E.
/// Pure functions, no torch, no state: safe to call from any thread.
///
/// Units: Pa, rad, N/m^3, m, N. Frame of the force: x along the direction of travel
/// (horizontal), z up; the force is that of the blade on the soil.
///
/// Symbols: c cohesion, phi internal friction angle, gamma unit weight, ca adhesion,
/// delta soil-tool friction angle, alpha surface slope (positive = terrain rises ahead of the
/// blade), rho rake angle (blade to horizontal, measured through the soil), d cutting depth,
/// w blade width in contact, Q surcharge weight, beta failure-plane angle.
#include <Eigen/Core>
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
struct Factors {
  double eta_rad = 0, N_gamma = 0, N_c = 0, N_Q = 0, N_ca = 0;
};

/// Which validity rule failed, or Valid.
enum class Validity {
  Valid, DepthNotPositive, WidthNotPositive, NegativeCohesion, NegativeAdhesion,
  NegativeUnitWeight, NegativeSurcharge, PhiOutOfRange, DeltaOutOfRange, AlphaOutOfRange,
  RhoOutOfRange, BetaOutOfRange, RhoPlusBetaTooLarge, EtaOutOfRange, AlphaPhiBetaOutOfRange,
  NotFinite
};
/// Human-readable rule, e.g. "0 < beta < pi/2".
const char* validityRule(Validity v);

struct Result {
  double beta_rad = 0;
  Factors n;
  double f_N = 0;                         ///< magnitude along the resultant's direction
  Eigen::Vector2d F_N = Eigen::Vector2d::Zero();        ///< paper's F = f [sin(rho+delta-alpha), cos(...)]
  Eigen::Vector2d F_total_N = Eigen::Vector2d::Zero();  ///< F + adhesion along the blade face
  Validity validity = Validity::Valid;
  bool valid() const { return validity == Validity::Valid; }
};

/// Nominal (Rankine) failure angle beta = pi/4 - phi/2.
double betaNominal(const Soil& s);
/// Failure angle beta* minimising N_gamma (closed form, ALGORITHMS.md §E); NaN if no admissible root.
double betaMin(const Soil& s, const Geometry& g);
/// Checks every validity rule for (soil, geometry, beta); returns the first that fails.
Validity check(const Soil& s, const Geometry& g, double beta_rad);
Factors factors(const Soil& s, const Geometry& g, double beta_rad);
/// Full evaluation at a given beta. Never throws; an invalid input is reported in `validity`
/// and the numbers are still computed where finite.
Result evaluate(const Soil& s, const Geometry& g, double beta_rad);

/// Parameter vector order for Jacobians: [c, phi, gamma, ca, delta, alpha, rho, d, w, Q, beta].
constexpr int kParamCount = 11;
using Jacobian = Eigen::Matrix<double, 2, kParamCount>;
/// Analytic dF/dTheta of the paper's F (not F_total), beta held as an independent parameter.
Jacobian jacobianF(const Soil& s, const Geometry& g, double beta_rad);
/// Analytic dF_total/dTheta.
Jacobian jacobianFTotal(const Soil& s, const Geometry& g, double beta_rad);

}  // namespace terramap::fee

#pragma once
// Helpers shared by the FEE tests: an independent world-frame trial-wedge force balance and
// random admissible parameter sets. Nothing here calls the library under test.
#include <terramap/soil/fee.hpp>

#include <Eigen/Dense>

#include <cmath>
#include <random>

namespace terramap::fee::test {

constexpr double kPi = 3.14159265358979323846;
constexpr double kDeg = kPi / 180.0;

/// Blade force of a trial wedge, from a 2D force polygon built with explicit vectors in the
/// world frame (x forward, z up) rather than the closed-form N-factors.
struct WedgeForce {
  double P = 0;               ///< magnitude of the blade reaction (normal + friction)
  Eigen::Vector2d resultant;  ///< P along its direction (the paper's F)
  Eigen::Vector2d total;      ///< resultant + adhesion (F_total)
};

/// Geometry: cutting edge at the origin; the surface line lies at normal distance d from the
/// edge and rises at alpha; the blade leaves the edge at rho from the surface line behind the
/// edge; the failure plane leaves the edge at beta from the surface line ahead of it.
inline WedgeForce wedgeForce(const Soil& s, const Geometry& g, double beta) {
  const double a = g.alpha_rad;
  const Eigen::Vector2d nS(-std::sin(a), std::cos(a));  // surface normal (up)
  const double angB = kPi + a - g.rho_rad;              // blade direction angle from +x
  const Eigen::Vector2d uB(std::cos(angB), std::sin(angB));
  const Eigen::Vector2d uF(std::cos(a + beta), std::sin(a + beta));
  const double lB = g.d_m / nS.dot(uB), lF = g.d_m / nS.dot(uF);
  const Eigen::Vector2d A = lB * uB, B = lF * uF;  // blade top, failure-plane exit
  const double area = 0.5 * std::abs(A.x() * B.y() - A.y() * B.x());
  const double W = s.gamma_n_m3 * g.w_m * area;
  // Normals pointing into the wedge.
  Eigen::Vector2d nB(-uB.y(), uB.x());
  if (nB.dot(B) < 0) nB = -nB;
  Eigen::Vector2d nF(-uF.y(), uF.x());
  if (nF.dot(A) < 0) nF = -nF;
  // The wedge slides up the blade face (along uB) and out along the failure plane (along uF):
  // friction, cohesion and adhesion on the wedge oppose those motions.
  const Eigen::Vector2d eP = nB * std::cos(s.delta_rad) - uB * std::sin(s.delta_rad);
  const Eigen::Vector2d eR = nF * std::cos(s.phi_rad) - uF * std::sin(s.phi_rad);
  const Eigen::Vector2d cohesion = -s.c_pa * g.w_m * lF * uF;
  const Eigen::Vector2d adhesion = -s.ca_pa * g.w_m * lB * uB;
  const Eigen::Vector2d weight(0.0, -(W + g.q_n));
  Eigen::Matrix2d M;
  M.col(0) = eP;
  M.col(1) = eR;
  const Eigen::Vector2d pr = M.fullPivLu().solve(-(weight + cohesion + adhesion));
  WedgeForce out;
  out.P = pr[0];
  out.resultant = pr[0] * eP;
  out.total = out.resultant + adhesion;
  return out;
}

/// N_gamma written out again for the numeric minimisation (independent of the library).
inline double nGammaRef(double phi, double delta, double alpha, double rho, double beta) {
  const double eta = delta + rho + phi + beta;
  return (std::cos(rho) / std::sin(rho) + std::cos(beta) / std::sin(beta)) * std::sin(alpha + phi + beta) /
         (2 * std::sin(eta));
}

/// Admissible beta interval (lo, hi) for the angles from the validity rules of ALGORITHMS.md §E.
inline void betaInterval(double phi, double delta, double alpha, double rho, double& lo, double& hi) {
  lo = std::max(0.0, -(alpha + phi));
  hi = std::min({kPi / 2, kPi - rho, kPi - (delta + rho + phi), kPi - (alpha + phi)});
}

/// A random parameter set that is valid with a margin `m` (rad) from every angular edge, so
/// finite differences stay inside the valid domain.
inline ParamVector randomAdmissible(std::mt19937_64& rng, double m = 0.05) {
  std::uniform_real_distribution<double> U(0.0, 1.0);
  auto u = [&](double a, double b) { return a + (b - a) * U(rng); };
  for (;;) {
    ParamVector p;
    p[kC] = u(0, 60e3);
    p[kPhi] = u(0.05, 0.85);
    p[kGamma] = u(12e3, 22e3);
    p[kCa] = u(0, 20e3);
    p[kDelta] = u(0.0, 0.75);
    p[kAlpha] = u(-0.45, 0.5);
    p[kRho] = u(0.35, 2.3);
    p[kD] = u(0.02, 0.6);
    p[kW] = u(0.2, 2.5);
    p[kQ] = u(0, 8e3);
    p[kBeta] = u(0.05, 1.5);
    const double eta = p[kDelta] + p[kRho] + p[kPhi] + p[kBeta];
    const double apb = p[kAlpha] + p[kPhi] + p[kBeta];
    if (p[kBeta] < m || p[kBeta] > kPi / 2 - m) continue;
    if (p[kRho] + p[kBeta] > kPi - m) continue;
    if (eta > kPi - m) continue;
    if (apb < m || apb > kPi - m) continue;
    return p;
  }
}

}  // namespace terramap::fee::test

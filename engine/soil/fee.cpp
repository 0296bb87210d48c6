// The fundamental equation of earthmoving (ALGORITHMS.md §E). The derivatives below were
// derived by hand from the N-factor formulas; the identities used are noted where they
// shorten an expression (e.g. cos A sin eta - sin A cos eta = sin(eta - A) = sin(delta+rho-alpha)).
#include <terramap/soil/fee.hpp>

#include <cmath>
#include <limits>

namespace terramap::fee {
namespace {

constexpr double kPi = 3.14159265358979323846;
constexpr double kHalfPi = kPi / 2;
constexpr double kNaN = std::numeric_limits<double>::quiet_NaN();
/// Below this, a, b and sin(delta - alpha) are rounding noise of terms of order 1.
constexpr double kFlatTol = 1e-12;

bool allFinite(const Soil& s, const Geometry& g) {
  return std::isfinite(s.c_pa) && std::isfinite(s.phi_rad) && std::isfinite(s.gamma_n_m3) &&
         std::isfinite(s.ca_pa) && std::isfinite(s.delta_rad) && std::isfinite(g.alpha_rad) &&
         std::isfinite(g.rho_rad) && std::isfinite(g.d_m) && std::isfinite(g.w_m) && std::isfinite(g.q_n);
}

/// Rules on the angles that beta* depends on, in check() order.
Validity checkAngles(const Soil& s, const Geometry& g) {
  if (!(s.phi_rad >= 0 && s.phi_rad < kHalfPi)) return Validity::PhiOutOfRange;
  if (!(s.delta_rad >= 0 && s.delta_rad < kHalfPi)) return Validity::DeltaOutOfRange;
  if (!(std::abs(g.alpha_rad) < kHalfPi)) return Validity::AlphaOutOfRange;
  if (!(g.rho_rad > 0 && g.rho_rad < kPi)) return Validity::RhoOutOfRange;
  return Validity::Valid;
}

/// Rules that involve beta, in check() order.
Validity checkBeta(const Soil& s, const Geometry& g, double beta) {
  if (!(beta > 0 && beta < kHalfPi)) return Validity::BetaOutOfRange;
  if (!(g.rho_rad + beta < kPi)) return Validity::RhoPlusBetaTooLarge;
  const double eta = s.delta_rad + g.rho_rad + s.phi_rad + beta;
  if (!(eta > 0 && eta < kPi)) return Validity::EtaOutOfRange;
  const double apb = g.alpha_rad + s.phi_rad + beta;
  if (!(apb > 0 && apb < kPi)) return Validity::AlphaPhiBetaOutOfRange;
  return Validity::Valid;
}

/// Every rule that does not involve beta, in check() order (NotFinite first).
Validity checkWithoutBeta(const Soil& s, const Geometry& g) {
  if (!allFinite(s, g)) return Validity::NotFinite;
  if (!(g.d_m > 0)) return Validity::DepthNotPositive;
  if (!(g.w_m > 0)) return Validity::WidthNotPositive;
  if (!(s.c_pa >= 0)) return Validity::NegativeCohesion;
  if (!(s.ca_pa >= 0)) return Validity::NegativeAdhesion;
  if (!(s.gamma_n_m3 >= 0)) return Validity::NegativeUnitWeight;
  if (!(g.q_n >= 0)) return Validity::NegativeSurcharge;
  return checkAngles(s, g);
}

double nGamma(double phi, double delta, double alpha, double rho, double beta) {
  const double eta = delta + rho + phi + beta;
  return (1.0 / std::tan(rho) + 1.0 / std::tan(beta)) * std::sin(alpha + phi + beta) / (2.0 * std::sin(eta));
}

/// Partial derivatives of the four N-factors w.r.t. the five angles.
struct FactorGrad {
  // index: 0 phi, 1 delta, 2 alpha, 3 rho, 4 beta
  double gamma[5], c[5], q[5], ca[5];
};

FactorGrad factorGrad(const Soil& s, const Geometry& g, double beta) {
  const double phi = s.phi_rad, delta = s.delta_rad, alpha = g.alpha_rad, rho = g.rho_rad;
  const double eta = delta + rho + phi + beta;
  const double A = alpha + phi + beta;  // angle in N_gamma, N_Q
  const double B = rho + phi + beta;    // angle in N_ca
  const double S = std::sin(eta), Ce = std::cos(eta), S2 = S * S;
  const double sA = std::sin(A), cA = std::cos(A);
  const double sB = std::sin(B), cB = std::cos(B);
  const double sr = std::sin(rho), cr = std::cos(rho);
  const double sb = std::sin(beta), cb = std::cos(beta);
  const double cphi = std::cos(phi);
  const double T = cr / sr + cb / sb;           // cot rho + cot beta
  const double sK1 = std::sin(delta + rho - alpha);  // = sin(eta - A)
  const double csc2r = 1.0 / (sr * sr), csc2b = 1.0 / (sb * sb);
  FactorGrad d{};
  // N_gamma = T sin A / (2 S)
  d.gamma[0] = T * sK1 / (2 * S2);
  d.gamma[1] = -T * sA * Ce / (2 * S2);
  d.gamma[2] = T * cA / (2 * S);
  d.gamma[3] = -sA * (csc2r * S + T * Ce) / (2 * S2);
  d.gamma[4] = (-csc2b * sA * S + T * sK1) / (2 * S2);
  // N_Q = sin A / S
  d.q[0] = sK1 / S2;
  d.q[1] = -sA * Ce / S2;
  d.q[2] = cA / S;
  d.q[3] = -sA * Ce / S2;
  d.q[4] = sK1 / S2;
  // N_c = cos phi / (sin beta S); sin phi S + cos phi cos eta = cos(eta - phi);
  // cos beta S + sin beta cos eta = sin(beta + eta)
  d.c[0] = -std::cos(eta - phi) / (sb * S2);
  d.c[1] = -cphi * Ce / (sb * S2);
  d.c[2] = 0;
  d.c[3] = -cphi * Ce / (sb * S2);
  d.c[4] = -cphi * std::sin(beta + eta) * csc2b / S2;
  // N_ca = -cos B / (sin rho S); sin B S + cos B cos eta = cos(eta - B) = cos delta;
  // d(sin rho S)/drho = cos rho S + sin rho cos eta = sin(rho + eta)
  d.ca[0] = std::cos(delta) / (sr * S2);
  d.ca[1] = cB * Ce / (sr * S2);
  d.ca[2] = 0;
  d.ca[3] = (sB * sr * S + cB * std::sin(rho + eta)) * csc2r / S2;
  d.ca[4] = std::cos(delta) / (sr * S2);
  return d;
}

}  // namespace

const char* validityRule(Validity v) {
  switch (v) {
    case Validity::Valid: return "valid";
    case Validity::DepthNotPositive: return "d > 0";
    case Validity::WidthNotPositive: return "w > 0";
    case Validity::NegativeCohesion: return "c >= 0";
    case Validity::NegativeAdhesion: return "ca >= 0";
    case Validity::NegativeUnitWeight: return "gamma >= 0";
    case Validity::NegativeSurcharge: return "Q >= 0";
    case Validity::PhiOutOfRange: return "0 <= phi < pi/2";
    case Validity::DeltaOutOfRange: return "0 <= delta < pi/2";
    case Validity::AlphaOutOfRange: return "|alpha| < pi/2";
    case Validity::RhoOutOfRange: return "0 < rho < pi";
    case Validity::BetaOutOfRange: return "0 < beta < pi/2";
    case Validity::RhoPlusBetaTooLarge: return "rho + beta < pi";
    case Validity::EtaOutOfRange: return "0 < eta = delta + rho + phi + beta < pi";
    case Validity::AlphaPhiBetaOutOfRange: return "0 < alpha + phi + beta < pi";
    case Validity::NotFinite: return "every parameter finite";
    case Validity::NoAdmissibleBeta: return "an admissible minimum-N_gamma beta* exists";
  }
  return "unknown";
}

const char* validityName(Validity v) {
  switch (v) {
    case Validity::Valid: return "Valid";
    case Validity::DepthNotPositive: return "DepthNotPositive";
    case Validity::WidthNotPositive: return "WidthNotPositive";
    case Validity::NegativeCohesion: return "NegativeCohesion";
    case Validity::NegativeAdhesion: return "NegativeAdhesion";
    case Validity::NegativeUnitWeight: return "NegativeUnitWeight";
    case Validity::NegativeSurcharge: return "NegativeSurcharge";
    case Validity::PhiOutOfRange: return "PhiOutOfRange";
    case Validity::DeltaOutOfRange: return "DeltaOutOfRange";
    case Validity::AlphaOutOfRange: return "AlphaOutOfRange";
    case Validity::RhoOutOfRange: return "RhoOutOfRange";
    case Validity::BetaOutOfRange: return "BetaOutOfRange";
    case Validity::RhoPlusBetaTooLarge: return "RhoPlusBetaTooLarge";
    case Validity::EtaOutOfRange: return "EtaOutOfRange";
    case Validity::AlphaPhiBetaOutOfRange: return "AlphaPhiBetaOutOfRange";
    case Validity::NotFinite: return "NotFinite";
    case Validity::NoAdmissibleBeta: return "NoAdmissibleBeta";
  }
  return "Unknown";
}

double betaNominal(const Soil& s) { return kPi / 4 - s.phi_rad / 2; }

double betaMin(const Soil& s, const Geometry& g) {
  const double phi = s.phi_rad, delta = s.delta_rad, alpha = g.alpha_rad, rho = g.rho_rad;
  if (!(std::isfinite(phi) && std::isfinite(delta) && std::isfinite(alpha) && std::isfinite(rho))) return kNaN;
  if (checkAngles(s, g) != Validity::Valid) return kNaN;
  // Stationarity of ln N_gamma: cot(rho+beta) - cot beta + cot(A) - cot eta = 0, i.e.
  // K1 sin(rho+beta) sin beta = K2 sin A sin eta; product-to-sum turns it into
  // a cos 2beta + b sin 2beta = sin(delta - alpha). The sign of dN_gamma/dbeta (inside the
  // admissible region all the sines are positive) is that of sin(delta-alpha) - R cos(2beta - t0),
  // which rises through zero at 2beta = t0 + acos(.) (minimum) and falls at t0 - acos(.).
  const double K1 = std::sin(delta + rho - alpha), K2 = std::sin(rho);
  const double E = alpha + delta + rho + 2 * phi;
  const double a = K1 * std::cos(rho) - K2 * std::cos(E);
  const double b = -K1 * std::sin(rho) + K2 * std::sin(E);
  const double R = std::hypot(a, b);
  const double rhs = std::sin(delta - alpha);
  if (R < kFlatTol && std::abs(rhs) < kFlatTol) {
    // dN_gamma/dbeta vanishes identically (e.g. phi = 0 against a smooth vertical blade on
    // level ground): every beta is a minimiser. Rankine's plane is the natural choice.
    const double nominal = betaNominal(s);
    return checkBeta(s, g, nominal) == Validity::Valid ? nominal : kNaN;
  }
  if (!(R > 0)) return kNaN;
  const double ratio = rhs / R;
  if (!(std::abs(ratio) <= 1)) return kNaN;
  const double t0 = std::atan2(b, a), half = std::acos(ratio);
  double best = kNaN, bestN = std::numeric_limits<double>::infinity();
  for (int k = -1; k <= 1; ++k) {
    const double beta = 0.5 * (t0 + half + 2 * kPi * k);
    if (checkBeta(s, g, beta) != Validity::Valid) continue;
    const double n = nGamma(phi, delta, alpha, rho, beta);
    if (n < bestN) {
      bestN = n;
      best = beta;
    }
  }
  return best;
}

Eigen::Vector2d betaMinGradient(const Soil& s, const Geometry& g) {
  const Eigen::Vector2d nan(kNaN, kNaN);
  if (!std::isfinite(betaMin(s, g))) return nan;
  const double phi = s.phi_rad, delta = s.delta_rad, alpha = g.alpha_rad, rho = g.rho_rad;
  const double K1 = std::sin(delta + rho - alpha), K2 = std::sin(rho), dK1 = std::cos(delta + rho - alpha);
  const double E = alpha + delta + rho + 2 * phi;
  const double a = K1 * std::cos(rho) - K2 * std::cos(E);
  const double b = -K1 * std::sin(rho) + K2 * std::sin(E);
  const double R = std::hypot(a, b);
  const double rhs = std::sin(delta - alpha);
  if (R < kFlatTol && std::abs(rhs) < kFlatTol) return {-0.5, 0.0};  // betaMin() returned Rankine's angle
  // Partial derivatives of a, b, rhs w.r.t. phi (dE/dphi = 2) and delta (dE/ddelta = 1).
  const double da[2] = {2 * K2 * std::sin(E), dK1 * std::cos(rho) + K2 * std::sin(E)};
  const double db[2] = {2 * K2 * std::cos(E), -dK1 * std::sin(rho) + K2 * std::cos(E)};
  const double dr[2] = {0.0, std::cos(delta - alpha)};
  const double u = rhs / R, root = std::sqrt(1 - u * u);
  if (!(root > 0)) return nan;  // acos at its pole: beta* is not differentiable there
  Eigen::Vector2d out;
  for (int k = 0; k < 2; ++k) {
    const double dt0 = (a * db[k] - b * da[k]) / (R * R);
    const double dR = (a * da[k] + b * db[k]) / R;
    const double du = (dr[k] * R - rhs * dR) / (R * R);
    out[k] = 0.5 * (dt0 - du / root);
  }
  return out;
}

Validity check(const Soil& s, const Geometry& g, double beta) {
  if (!std::isfinite(beta)) return Validity::NotFinite;
  const Validity v = checkWithoutBeta(s, g);
  return v != Validity::Valid ? v : checkBeta(s, g, beta);
}

Factors factors(const Soil& s, const Geometry& g, double beta) {
  const double phi = s.phi_rad, delta = s.delta_rad, alpha = g.alpha_rad, rho = g.rho_rad;
  Factors n;
  n.eta_rad = delta + rho + phi + beta;
  const double S = std::sin(n.eta_rad);
  n.N_gamma = nGamma(phi, delta, alpha, rho, beta);
  n.N_c = std::cos(phi) / (std::sin(beta) * S);
  n.N_Q = std::sin(alpha + phi + beta) / S;
  n.N_ca = -std::cos(rho + phi + beta) / (std::sin(rho) * S);
  return n;
}

Result evaluate(const Soil& s, const Geometry& g, double beta) { return evaluateWith(s, g, beta, factors(s, g, beta)); }

Result evaluateWith(const Soil& s, const Geometry& g, double beta, const Factors& n) {
  Result r;
  r.beta_rad = beta;
  r.validity = check(s, g, beta);
  r.n = n;
  const double d = g.d_m, w = g.w_m;
  r.f_N = s.gamma_n_m3 * d * d * w * r.n.N_gamma + s.c_pa * d * w * r.n.N_c + g.q_n * r.n.N_Q +
          s.ca_pa * d * w * r.n.N_ca;
  const double th = g.rho_rad + s.delta_rad - g.alpha_rad;
  r.F_N = r.f_N * Eigen::Vector2d(std::sin(th), std::cos(th));
  // Adhesion acts along the blade face over its wetted length d / sin rho, against the soil's
  // upward slide: direction (cos(rho - alpha), -sin(rho - alpha)) in the world frame.
  const double psi = g.rho_rad - g.alpha_rad;
  const double adhesion = s.ca_pa * d * w / std::sin(g.rho_rad);
  r.F_total_N = r.F_N + adhesion * Eigen::Vector2d(std::cos(psi), -std::sin(psi));
  return r;
}

Result evaluateAtBetaNominal(const Soil& s, const Geometry& g) { return evaluate(s, g, betaNominal(s)); }

Result evaluateAtBetaMin(const Soil& s, const Geometry& g) {
  const double beta = betaMin(s, g);
  Result r = evaluate(s, g, beta);
  if (std::isnan(beta)) {
    // Report the real cause when a beta-independent rule already fails; otherwise the FEE
    // is well posed but has no failure plane of minimum resistance.
    const Validity other = checkWithoutBeta(s, g);
    r.validity = other == Validity::Valid ? Validity::NoAdmissibleBeta : other;
  }
  return r;
}

double dNgammaDbeta(const Soil& s, const Geometry& g, double beta) { return factorGrad(s, g, beta).gamma[4]; }

ParamVector pack(const Soil& s, const Geometry& g, double beta) {
  ParamVector p;
  p << s.c_pa, s.phi_rad, s.gamma_n_m3, s.ca_pa, s.delta_rad, g.alpha_rad, g.rho_rad, g.d_m, g.w_m, g.q_n, beta;
  return p;
}

void unpack(const ParamVector& p, Soil& s, Geometry& g, double& beta) {
  s.c_pa = p[kC];
  s.phi_rad = p[kPhi];
  s.gamma_n_m3 = p[kGamma];
  s.ca_pa = p[kCa];
  s.delta_rad = p[kDelta];
  g.alpha_rad = p[kAlpha];
  g.rho_rad = p[kRho];
  g.d_m = p[kD];
  g.w_m = p[kW];
  g.q_n = p[kQ];
  beta = p[kBeta];
}

Jacobian jacobianF(const Soil& s, const Geometry& g, double beta) {
  const Factors n = factors(s, g, beta);
  const FactorGrad dn = factorGrad(s, g, beta);
  const double c = s.c_pa, gam = s.gamma_n_m3, ca = s.ca_pa, d = g.d_m, w = g.w_m, Q = g.q_n;
  const double f = gam * d * d * w * n.N_gamma + c * d * w * n.N_c + Q * n.N_Q + ca * d * w * n.N_ca;
  // df/dTheta
  double df[kParamCount];
  df[kC] = d * w * n.N_c;
  df[kGamma] = d * d * w * n.N_gamma;
  df[kCa] = d * w * n.N_ca;
  df[kQ] = n.N_Q;
  df[kD] = 2 * gam * d * w * n.N_gamma + c * w * n.N_c + ca * w * n.N_ca;
  df[kW] = gam * d * d * n.N_gamma + c * d * n.N_c + ca * d * n.N_ca;
  const int angleIndex[5] = {kPhi, kDelta, kAlpha, kRho, kBeta};
  for (int i = 0; i < 5; ++i)
    df[angleIndex[i]] = gam * d * d * w * dn.gamma[i] + c * d * w * dn.c[i] + Q * dn.q[i] + ca * d * w * dn.ca[i];
  // F = f u(theta), theta = rho + delta - alpha, u = (sin, cos), u' = (cos, -sin).
  const double th = g.rho_rad + s.delta_rad - g.alpha_rad;
  const Eigen::Vector2d u(std::sin(th), std::cos(th)), du(std::cos(th), -std::sin(th));
  Jacobian J;
  for (int j = 0; j < kParamCount; ++j) J.col(j) = df[j] * u;
  J.col(kRho) += f * du;
  J.col(kDelta) += f * du;
  J.col(kAlpha) -= f * du;
  return J;
}

Jacobian jacobianFTotal(const Soil& s, const Geometry& g, double beta) {
  Jacobian J = jacobianF(s, g, beta);
  // G = ca d w csc(rho) v(psi), psi = rho - alpha, v = (cos, -sin), v' = (-sin, -cos).
  const double rho = g.rho_rad, psi = rho - g.alpha_rad;
  const double csc = 1.0 / std::sin(rho), cot = std::cos(rho) / std::sin(rho);
  const double ca = s.ca_pa, d = g.d_m, w = g.w_m;
  const Eigen::Vector2d v(std::cos(psi), -std::sin(psi)), dv(-std::sin(psi), -std::cos(psi));
  const double G = ca * d * w * csc;
  J.col(kCa) += d * w * csc * v;
  J.col(kD) += ca * w * csc * v;
  J.col(kW) += ca * d * csc * v;
  J.col(kRho) += -G * cot * v + G * dv;
  J.col(kAlpha) -= G * dv;
  return J;
}

BearingFactors bearingFactors(double phi) {
  BearingFactors b;
  if (phi < 1e-6) {
    // Series at phi -> 0: N_q = 1 + (pi + 2) phi + ..., N_c = pi + 2 + (pi^2/2 + pi + 1 ... ) phi;
    // the constant terms are all the estimator's ranges (phi >= 10 deg) ever meet here.
    b.N_q = 1.0;
    b.N_c = M_PI + 2.0;
    b.dN_q = M_PI + 2.0;
    b.dN_c = 0.0;
    return b;
  }
  const double t = std::tan(phi), sec2 = 1.0 + t * t;
  const double u = std::tan(M_PI / 4 + phi / 2);
  b.N_q = std::exp(M_PI * t) * u * u;
  b.N_c = (b.N_q - 1.0) / t;
  // d/dphi ln N_q = pi sec^2 phi + 2 * (1/2) sec^2(u) / tan(u) = pi sec^2 phi + 2 / cos phi.
  b.dN_q = b.N_q * (M_PI * sec2 + 2.0 / std::cos(phi));
  b.dN_c = b.dN_q / t - (b.N_q - 1.0) * sec2 / (t * t);
  return b;
}

Penetration penetration(const Soil& s, double d_m, double w_m, double edge_m) {
  return penetrationWith(s, d_m, w_m, edge_m, bearingFactors(s.phi_rad));
}

Penetration penetrationWith(const Soil& s, double d_m, double w_m, double edge_m, const BearingFactors& b) {
  const double a = edge_m * w_m;
  Penetration p;
  p.force_n = (s.c_pa * b.N_c + s.gamma_n_m3 * d_m * b.N_q) * edge_m * w_m;
  p.gradient = {b.N_c * a, (s.c_pa * b.dN_c + s.gamma_n_m3 * d_m * b.dN_q) * a, d_m * b.N_q * a, s.gamma_n_m3 * b.N_q * a};
  return p;
}

}  // namespace terramap::fee

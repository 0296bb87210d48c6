// The FEE as a torch layer (ALGORITHMS.md §E): the formulas of engine/soil/fee.cpp written
// with ATen ops so that autograd differentiates them.
#include "fee_torch.hpp"

#include <c10/core/GradMode.h>
#include <torch/csrc/autograd/autograd.h>

#include <cmath>
#include <limits>
#include <stdexcept>
#include <string>
#include <vector>

namespace terramap::pinn {
namespace {

constexpr double kPi = 3.14159265358979323846;
constexpr double kHalfPi = kPi / 2;

/// Every FEE input as a [B,P] float64 tensor.
struct Inputs {
  at::Tensor c, phi, ca, delta, gamma, rho, alpha, w, d, q, beta;
};

void requireShape(const at::Tensor& t, const char* name, at::IntArrayRef shape) {
  if (!t.defined() || t.sizes() != shape)
    throw std::invalid_argument(std::string("feeForward: ") + name + " must have shape " +
                                c10::str(shape) + (t.defined() ? ", got " + c10::str(t.sizes()) : ", got none"));
}

Inputs expandInputs(const at::Tensor& soil, const at::Tensor& rho, const at::Tensor& alpha, const at::Tensor& w,
                    const at::Tensor& d, const at::Tensor& q, const at::Tensor& beta) {
  if (!rho.defined() || rho.dim() != 2) throw std::invalid_argument("feeForward: rho must be [B,P]");
  const int64_t B = rho.size(0), P = rho.size(1);
  requireShape(soil, "soil", {B, kSoilCount});
  requireShape(alpha, "alpha", {B, P});
  requireShape(w, "w", {B, P});
  requireShape(d, "d", {B, P});
  requireShape(q, "q", {B, P});
  at::Tensor b = beta.defined() && beta.dim() == 1 ? beta.unsqueeze(1).expand({B, P}) : beta;
  requireShape(b, "beta ([B] or [B,P])", {B, P});
  const at::Tensor s = soil.to(at::kDouble);
  auto col = [&](int k) { return s.select(1, k).unsqueeze(1).expand({B, P}); };
  auto dbl = [](const at::Tensor& t) { return t.to(at::kDouble); };
  return {col(kSoilC), col(kSoilPhi), col(kSoilCa), col(kSoilDelta), col(kSoilGamma), dbl(rho), dbl(alpha),
          dbl(w), dbl(d), dbl(q), dbl(b)};
}

/// fee::check() == Valid, element-wise. NaN fails every comparison, so only infinities need
/// the explicit finiteness test.
at::Tensor validOf(const Inputs& in) {
  at::Tensor ok = at::ones_like(in.rho, at::kBool);
  for (const at::Tensor* t : {&in.c, &in.phi, &in.ca, &in.delta, &in.gamma, &in.rho, &in.alpha, &in.w, &in.d, &in.q,
                              &in.beta})
    ok = ok & at::isfinite(*t);
  ok = ok & (in.d > 0) & (in.w > 0) & (in.c >= 0) & (in.ca >= 0) & (in.gamma >= 0) & (in.q >= 0);
  ok = ok & (in.phi >= 0) & (in.phi < kHalfPi) & (in.delta >= 0) & (in.delta < kHalfPi);
  ok = ok & (at::abs(in.alpha) < kHalfPi) & (in.rho > 0) & (in.rho < kPi);
  ok = ok & (in.beta > 0) & (in.beta < kHalfPi) & (in.rho + in.beta < kPi);
  const at::Tensor eta = in.delta + in.rho + in.phi + in.beta;
  const at::Tensor apb = in.alpha + in.phi + in.beta;
  return ok & (eta > 0) & (eta < kPi) & (apb > 0) & (apb < kPi);
}

/// x where valid, else an admissible stand-in value (see the header on invalid entries).
at::Tensor pick(const at::Tensor& valid, const at::Tensor& x, double standin) {
  return at::where(valid, x, at::full_like(x, standin));
}


/// The FEE on [B,P] float64 inputs; F etc. in float64.
FeeOut evaluate(const Inputs& raw) {
  FeeOut o;
  o.valid = validOf(raw);
  o.beta = raw.beta;
  o.eta = raw.delta + raw.rho + raw.phi + raw.beta;
  const at::Tensor& v = o.valid;
  // Stand-in: a level cut by a 69 deg blade in a frictional soil, far from every pole.
  const at::Tensor phi = pick(v, raw.phi, 0.5), delta = pick(v, raw.delta, 0.3), alpha = pick(v, raw.alpha, 0.0);
  const at::Tensor rho = pick(v, raw.rho, 1.2), beta = pick(v, raw.beta, 0.5);
  const at::Tensor c = pick(v, raw.c, 0.0), ca = pick(v, raw.ca, 0.0), gamma = pick(v, raw.gamma, 0.0);
  const at::Tensor d = pick(v, raw.d, 0.1), w = pick(v, raw.w, 1.0), q = pick(v, raw.q, 0.0);
  // Paper Eq. 2 / fee.hpp Factors.
  const at::Tensor S = at::sin(delta + rho + phi + beta);
  const at::Tensor sA = at::sin(alpha + phi + beta);
  const at::Tensor Ng = (1.0 / at::tan(rho) + 1.0 / at::tan(beta)) * sA / (2.0 * S);
  const at::Tensor Nc = at::cos(phi) / (at::sin(beta) * S);
  const at::Tensor NQ = sA / S;
  const at::Tensor Nca = -at::cos(rho + phi + beta) / (at::sin(rho) * S);
  // Paper Eq. 1.
  const at::Tensor dw = d * w;
  const at::Tensor f = gamma * d * dw * Ng + c * dw * Nc + q * NQ + ca * dw * Nca;
  const at::Tensor th = rho + delta - alpha;
  const at::Tensor F = at::stack({f * at::sin(th), f * at::cos(th)}, -1);
  o.F = at::where(v.unsqueeze(-1), F, at::zeros_like(F));
  o.N_gamma = at::where(v, Ng, at::zeros_like(Ng));
  o.N_c = at::where(v, Nc, at::zeros_like(Nc));
  o.N_Q = at::where(v, NQ, at::zeros_like(NQ));
  o.N_ca = at::where(v, Nca, at::zeros_like(Nca));
  return o;
}

}  // namespace

FeeOut feeForward(const at::Tensor& soil, const at::Tensor& rho, const at::Tensor& alpha, const at::Tensor& w,
                  const at::Tensor& d, const at::Tensor& q, const at::Tensor& beta) {
  FeeOut o = evaluate(expandInputs(soil, rho, alpha, w, d, q, beta));
  const auto dt = soil.scalar_type();
  for (at::Tensor* t : {&o.F, &o.N_gamma, &o.N_c, &o.N_Q, &o.N_ca, &o.eta, &o.beta}) *t = t->to(dt);
  return o;
}

at::Tensor betaNominal(const at::Tensor& phi) { return kPi / 4 - phi / 2; }

BetaMinOut betaMinTorch(const at::Tensor& phi_in, const at::Tensor& delta_in, const at::Tensor& alpha_in,
                        const at::Tensor& rho_in, const at::Tensor& fallback) {
  const std::vector<at::Tensor> bc =
      at::broadcast_tensors({phi_in.to(at::kDouble), delta_in.to(at::kDouble), alpha_in.to(at::kDouble),
                             rho_in.to(at::kDouble), fallback.to(at::kDouble)});
  const at::Tensor &phi0 = bc[0], &delta0 = bc[1], &alpha0 = bc[2], &rho0 = bc[3], &fb = bc[4];
  // fee.cpp checkAngles(): outside these the closed form means nothing.
  const at::Tensor angles_ok = at::isfinite(phi0) & at::isfinite(delta0) & at::isfinite(alpha0) &
                               at::isfinite(rho0) & (phi0 >= 0) & (phi0 < kHalfPi) & (delta0 >= 0) &
                               (delta0 < kHalfPi) & (at::abs(alpha0) < kHalfPi) & (rho0 > 0) & (rho0 < kPi);
  // Stand-ins where the angles are out of range (the "double where" trick of the header).
  const at::Tensor phi = pick(angles_ok, phi0, 0.5), delta = pick(angles_ok, delta0, 0.3);
  const at::Tensor alpha = pick(angles_ok, alpha0, 0.0), rho = pick(angles_ok, rho0, 1.2);
  const at::Tensor K1 = at::sin(delta + rho - alpha), K2 = at::sin(rho);
  const at::Tensor E = alpha + delta + rho + 2.0 * phi;
  const at::Tensor a = K1 * at::cos(rho) - K2 * at::cos(E);
  const at::Tensor b = -K1 * at::sin(rho) + K2 * at::sin(E);
  const at::Tensor R2 = a * a + b * b;
  const at::Tensor rhs = at::sin(delta - alpha);
  // hypot's gradient is 0/0 at R = 0 and acos' infinite at +-1: keep both away by stand-ins.
  const at::Tensor ratio_raw = rhs / at::sqrt(at::clamp_min(R2, 1e-300));
  const at::Tensor ok = angles_ok & (R2 > 1e-24) & (at::abs(ratio_raw) < 1.0 - 1e-9);
  const at::Tensor ratio = pick(ok, ratio_raw, 0.0);
  const at::Tensor t0 = at::atan2(pick(ok, b, 1.0), pick(ok, a, 1.0));
  const at::Tensor half = at::acos(ratio);
  // The three candidate roots (k = -1, 0, 1); each admissible one competes on N_gamma.
  at::Tensor best = fb, best_n = at::full_like(fb, std::numeric_limits<double>::infinity());
  at::Tensor found = at::zeros_like(ok);
  for (int k = -1; k <= 1; ++k) {
    const at::Tensor beta_k = 0.5 * (t0 + half) + kPi * k;
    const at::Tensor eta = delta + rho + phi + beta_k, apb = alpha + phi + beta_k;
    const at::Tensor adm = ok & (beta_k > 0) & (beta_k < kHalfPi) & (rho + beta_k < kPi) & (eta > 0) & (eta < kPi) &
                           (apb > 0) & (apb < kPi);
    const at::Tensor bs = pick(adm, beta_k, 0.5);
    const at::Tensor ng = (1.0 / at::tan(rho) + 1.0 / at::tan(bs)) * at::sin(alpha + phi + bs) /
                          (2.0 * at::sin(delta + rho + phi + bs));
    const at::Tensor better = adm & (ng.detach() < best_n);
    best = at::where(better, beta_k, best);
    best_n = at::where(better, ng.detach(), best_n);
    found = found | adm;
  }
  return {at::where(found, best, fb), found};
}

at::Tensor dNgammaDbeta(const at::Tensor& phi, const at::Tensor& delta, const at::Tensor& alpha, const at::Tensor& rho,
                        const at::Tensor& beta) {
  // fee.cpp factorGrad: (-csc^2 beta sin A sin eta + (cot rho + cot beta) sin(delta+rho-alpha)) / (2 sin^2 eta)
  const at::Tensor S = at::sin(delta + rho + phi + beta);
  const at::Tensor sb = at::sin(beta);
  const at::Tensor T = 1.0 / at::tan(rho) + 1.0 / at::tan(beta);
  const at::Tensor sK1 = at::sin(delta + rho - alpha);
  return (-at::sin(alpha + phi + beta) * S / (sb * sb) + T * sK1) / (2.0 * S * S);
}

at::Tensor feeValid(const at::Tensor& soil, const at::Tensor& rho, const at::Tensor& alpha, const at::Tensor& w,
                    const at::Tensor& d, const at::Tensor& q, const at::Tensor& beta) {
  return validOf(expandInputs(soil, rho, alpha, w, d, q, beta));
}

const char* betaBaseName(BetaBase b) { return b == BetaBase::Min ? "min" : "nominal"; }

BetaBase parseBetaBase(const std::string& s) {
  if (s == "min") return BetaBase::Min;
  if (s == "nominal") return BetaBase::Nominal;
  throw std::invalid_argument("beta_base: '" + s + "' is neither 'min' (beta* minimising N_gamma) nor 'nominal' (pi/4 - phi/2)");
}

at::Tensor failureAngle(BetaBase base, const at::Tensor& phi, const at::Tensor& delta, const at::Tensor& alpha,
                        const at::Tensor& rho) {
  auto perStep = [&](const at::Tensor& x) {
    const at::Tensor t = x.to(at::kDouble);
    return t.dim() == 1 ? t.unsqueeze(1).expand_as(rho) : t;
  };
  const at::Tensor phi2 = perStep(phi);
  const at::Tensor nominal = betaNominal(phi2);
  if (base == BetaBase::Nominal) return nominal;
  return betaMinTorch(phi2, perStep(delta), alpha.to(at::kDouble), rho.to(at::kDouble), nominal).beta;
}

namespace {

/// Autograd Jacobian dF/d[c, phi, ca, delta, gamma, d, x] on fresh [B,P] leaves, with beta
/// built from the leaves by `beta_of(in, x)` (x the last leaf). Every F[b,p] depends only on
/// the leaves' entry [b,p], so the gradient of sum(F_x) w.r.t. a leaf is the per-entry
/// derivative. Two backward passes.
template <class BetaOf>
at::Tensor jacobianWith(Inputs in, const at::Tensor& x0, BetaOf beta_of) {
  c10::AutoGradMode grad_on(true);
  std::vector<at::Tensor*> cols(kJacCount - 1);
  cols[kJacC] = &in.c;
  cols[kJacPhi] = &in.phi;
  cols[kJacCa] = &in.ca;
  cols[kJacDelta] = &in.delta;
  cols[kJacGamma] = &in.gamma;
  cols[kJacD] = &in.d;
  std::vector<at::Tensor> leaves;
  for (at::Tensor* t : cols) {
    *t = t->contiguous().clone().requires_grad_(true);
    leaves.push_back(*t);
  }
  const at::Tensor x = x0.contiguous().clone().requires_grad_(true);
  leaves.push_back(x);
  in.beta = beta_of(in, x);
  const FeeOut o = evaluate(in);
  std::vector<at::Tensor> rows;
  for (int k = 0; k < 2; ++k) {
    auto g = torch::autograd::grad({o.F.select(-1, k).sum()}, leaves, {}, /*retain_graph=*/k == 0,
                                   /*create_graph=*/false, /*allow_unused=*/true);
    for (size_t j = 0; j < g.size(); ++j)
      if (!g[j].defined()) g[j] = at::zeros_like(leaves[j]);
    rows.push_back(at::stack(g, -1));  // [B,P,7]
  }
  return at::stack(rows, -2).detach();  // [B,P,2,7]
}

}  // namespace

at::Tensor feeJacobian(const at::Tensor& soil, const at::Tensor& rho, const at::Tensor& alpha, const at::Tensor& w,
                       const at::Tensor& d, const at::Tensor& q, const at::Tensor& beta) {
  Inputs in = expandInputs(soil.detach(), rho.detach(), alpha.detach(), w.detach(), d.detach(), q.detach(),
                           beta.detach());
  const at::Tensor b = in.beta;
  return jacobianWith(std::move(in), b, [](const Inputs&, const at::Tensor& x) { return x; });
}

at::Tensor feeJacobianChained(const at::Tensor& soil, const at::Tensor& rho, const at::Tensor& alpha,
                              const at::Tensor& w, const at::Tensor& d, const at::Tensor& q,
                              const at::Tensor& beta_res, BetaBase base) {
  if (!beta_res.defined() || beta_res.dim() != 1 || beta_res.size(0) != rho.size(0))
    throw std::invalid_argument("feeJacobianChained: beta_res must be [B]");
  const at::Tensor res = beta_res.detach().to(at::kDouble).unsqueeze(1).expand_as(rho);
  Inputs in = expandInputs(soil.detach(), rho.detach(), alpha.detach(), w.detach(), d.detach(), q.detach(), res);
  const at::Tensor r = in.beta;
  return jacobianWith(std::move(in), r, [base](const Inputs& v, const at::Tensor& x) {
    return failureAngle(base, v.phi, v.delta, v.alpha, v.rho) + x;
  });
}

PenetrationOut penetrationForward(const at::Tensor& soil, const at::Tensor& w, const at::Tensor& d,
                                  const at::Tensor& gate, double edge_m) {
  // The formulas of fee::bearingFactors (phi >= 10 deg in the estimator's ranges, so no
  // phi -> 0 branch is needed here).
  auto col = [&](const at::Tensor& s, int k) { return s.select(1, k).unsqueeze(1); };  // [B,1]
  const at::Tensor phi = col(soil, kSoilPhi), c = col(soil, kSoilC), gam = col(soil, kSoilGamma);
  const at::Tensor t = at::tan(phi), sec2 = 1.0 + t * t, u = at::tan(M_PI / 4 + phi / 2);
  const at::Tensor nq = at::exp(M_PI * t) * u * u;
  const at::Tensor nc = (nq - 1.0) / t;
  PenetrationOut out;
  out.Fz = -gate * (c * nc + gam * d * nq) * (edge_m * w);
  // The Jacobian from the same factors, detached (the derivatives in closed form).
  const at::Tensor nqd = nq.detach(), ncd = nc.detach(), td = t.detach(), sec2d = sec2.detach();
  const at::Tensor dnq = nqd * (M_PI * sec2d + 2.0 / at::cos(phi.detach()));
  const at::Tensor dnc = dnq / td - (nqd - 1.0) * sec2d / (td * td);
  const at::Tensor g = gate.detach(), dd = d.detach(), a = edge_m * w.detach();
  const at::Tensor cd = c.detach(), gd = gam.detach();
  const at::Tensor zero = at::zeros_like(dd);
  std::vector<at::Tensor> zrow(kJacCount, zero);
  zrow[kJacC] = -g * ncd * a;
  zrow[kJacPhi] = -g * (cd * dnc + gd * dd * dnq) * a;
  zrow[kJacGamma] = -g * dd * nqd * a;
  zrow[kJacD] = -g * gd * nqd * a;  // through d_res
  const at::Tensor xrow = at::zeros({dd.size(0), dd.size(1), kJacCount}, dd.options());
  out.J = at::stack({xrow, at::stack(zrow, -1)}, -2);
  return out;
}

}  // namespace terramap::pinn

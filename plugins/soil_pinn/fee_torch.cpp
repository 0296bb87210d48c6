// The FEE as a torch layer (ALGORITHMS.md §E): the formulas of engine/soil/fee.cpp written
// with ATen ops so that autograd differentiates them.
#include "fee_torch.hpp"

#include <c10/core/GradMode.h>
#include <torch/csrc/autograd/autograd.h>

#include <cmath>
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

at::Tensor feeJacobian(const at::Tensor& soil, const at::Tensor& rho, const at::Tensor& alpha, const at::Tensor& w,
                       const at::Tensor& d, const at::Tensor& q, const at::Tensor& beta) {
  // Autograd on fresh [B,P] leaves: every F[b,p] depends only on the leaves' entry [b,p], so
  // the gradient of sum(F_x) w.r.t. a leaf is the per-entry derivative. Two backward passes.
  c10::AutoGradMode grad_on(true);
  Inputs in = expandInputs(soil.detach(), rho.detach(), alpha.detach(), w.detach(), d.detach(), q.detach(),
                           beta.detach());
  std::vector<at::Tensor*> cols(kJacCount);
  cols[kJacC] = &in.c;
  cols[kJacPhi] = &in.phi;
  cols[kJacCa] = &in.ca;
  cols[kJacDelta] = &in.delta;
  cols[kJacGamma] = &in.gamma;
  cols[kJacD] = &in.d;
  cols[kJacBeta] = &in.beta;
  std::vector<at::Tensor> leaves;
  for (at::Tensor* t : cols) {
    *t = t->contiguous().clone().requires_grad_(true);
    leaves.push_back(*t);
  }
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

}  // namespace terramap::pinn

// Paper Eq. 7 with a truncated SVD (see nullspace.hpp for why max, not min).
#include "nullspace.hpp"

#include "model.hpp"

#include <stdexcept>
#include <tuple>

namespace terramap::pinn {

at::Tensor nullspaceProjector(const at::Tensor& J, const NullspaceTolerances& tol) {
  if (J.dim() < 2) throw std::invalid_argument("nullspaceProjector: J must be [..., m, n]");
  const at::Tensor A = J.to(at::kDouble);
  const int64_t n = A.size(-1);
  // J = U diag(s) Vh; J^+ J = Vh^T diag(kept) Vh, so it needs no explicit inverse.
  at::Tensor U, s, Vh;
  std::tie(U, s, Vh) = at::linalg_svd(A, /*full_matrices=*/false);
  const at::Tensor s_max = std::get<0>(s.max(-1, /*keepdim=*/true));
  const at::Tensor cutoff = at::clamp_min(tol.r_tol * s_max, tol.a_tol);
  const at::Tensor kept = (s > cutoff).to(at::kDouble);  // [..., k]
  const at::Tensor V = Vh.transpose(-2, -1);              // [..., n, k]
  const at::Tensor range = at::matmul(V * kept.unsqueeze(-2), Vh);
  return at::eye(n, A.options()) - range;
}

at::Tensor nullspaceCovariance(const at::Tensor& J, const at::Tensor& sigma_a, const NullspaceTolerances& tol) {
  at::Tensor Sa = sigma_a.to(at::kDouble);
  if (Sa.dim() == 1) Sa = at::diag(Sa);
  if (Sa.dim() != 2 || Sa.size(0) != J.size(-1) || Sa.size(1) != J.size(-1))
    throw std::invalid_argument("nullspaceCovariance: sigma_a must be [n] or [n,n] with n = J.size(-1)");
  return at::matmul(nullspaceProjector(J, tol), Sa);
}

at::Tensor inflateVariances(const at::Tensor& var_theta, const at::Tensor& sigma_n) {
  return at::maximum(var_theta.to(at::kDouble), at::diagonal(sigma_n.to(at::kDouble), 0, -2, -1));
}

at::Tensor stackHorizon(const at::Tensor& J_steps) {
  if (J_steps.dim() != 4) throw std::invalid_argument("stackHorizon: expected [B,P,2,K]");
  return J_steps.reshape({J_steps.size(0), J_steps.size(1) * J_steps.size(2), J_steps.size(3)});
}

at::Tensor soilVariances(const at::Tensor& J_steps, const at::Tensor& log_var, const at::Tensor& sigma_a,
                         const NullspaceTolerances& tol) {
  if (J_steps.dim() != 4 || J_steps.size(-1) < kSoilCount || log_var.dim() != 2 || log_var.size(1) < kSoilCount)
    throw std::invalid_argument("soilVariances: expected J [B,P,2,K>=5] and log_var [B,K>=5]");
  const at::Tensor J = stackHorizon(J_steps.narrow(-1, 0, kSoilCount));
  const at::Tensor var = at::exp(log_var.narrow(1, 0, kSoilCount).to(at::kDouble));
  return inflateVariances(var, nullspaceCovariance(J, sigma_a, tol));
}

at::Tensor defaultAmbiguityVariance() {
  const soil::SoilParamVector u = soil::uniformRangeVariances();
  at::Tensor v = at::empty({kSoilCount}, at::kDouble);
  for (int k = 0; k < kSoilCount; ++k) v[k] = u[static_cast<std::size_t>(k)];
  return v;
}

}  // namespace terramap::pinn

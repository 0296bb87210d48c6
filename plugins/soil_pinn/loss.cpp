// Paper Eq. 8 (see loss.hpp for each term's definition and normalisation).
#include "loss.hpp"

#include <stdexcept>

namespace terramap::pinn {
namespace {

/// Range penalty of x [B] against [lo, hi], in spans.
at::Tensor outside(const at::Tensor& x, double lo, double hi) {
  const double span = hi - lo;
  return at::relu((x - hi) / span) + at::relu((lo - x) / span);
}

/// Eq. 3 per entry for 2x2 covariances, closed form; entries where !m use the stand-in
/// Sigma = I, r = 0 so no division by a zero determinant ever happens.
at::Tensor nll2(const at::Tensor& r, const at::Tensor& Sigma, const at::Tensor& m, double floor_n2) {
  auto sel = [&](int i, int j) { return Sigma.select(-2, i).select(-1, j); };
  const at::Tensor one = at::ones_like(m, at::kDouble), zero = at::zeros_like(m, at::kDouble);
  const at::Tensor a = at::where(m, sel(0, 0) + floor_n2, one), b = at::where(m, sel(0, 1), zero);
  const at::Tensor c = at::where(m, sel(1, 0), zero), d = at::where(m, sel(1, 1) + floor_n2, one);
  const at::Tensor r0 = at::where(m, r.select(-1, 0), zero), r1 = at::where(m, r.select(-1, 1), zero);
  const at::Tensor det = a * d - b * c;
  const at::Tensor quad = (d * r0 * r0 - (b + c) * r0 * r1 + a * r1 * r1) / det;
  return at::where(m, 0.5 * (quad + at::log(det)), zero);
}

/// The prior's and the soil term's shape: the batch mean of sum_k ((th_k - centre(k)) / span_k)^2
/// over the soil properties, centre(k) a value or a [B] column.
template <class Centre>
at::Tensor spanDistance2(const at::Tensor& th, Centre centre) {
  at::Tensor sq = at::zeros({th.size(0)}, at::kDouble);
  for (int k = 0; k < kSoilCount; ++k) {
    const at::Tensor z = (th.select(1, k) - centre(k)) / (kSoilRanges[k].hi - kSoilRanges[k].lo);
    sq = sq + z * z;
  }
  return sq.mean();
}

}  // namespace

LossTerms pinnLoss(const PinnOutput& out, const at::Tensor& force, const LossWeights& w, const at::Tensor& row_mask,
                   const at::Tensor& truth) {
  if (!out.F.defined() || force.sizes() != out.F.sizes())
    throw std::invalid_argument("pinnLoss: force must be [B,P,2] like the prediction, got " + c10::str(force.sizes()));
  const int64_t B = out.F.size(0), P = out.F.size(1);
  const double N = static_cast<double>(B * P);
  if (row_mask.defined() && row_mask.sizes() != out.valid.sizes())
    throw std::invalid_argument("pinnLoss: row_mask must be [B,P] like the prediction, got " + c10::str(row_mask.sizes()));
  if (truth.defined() && (truth.dim() != 2 || truth.size(0) != B || truth.size(1) != kSoilCount))
    throw std::invalid_argument("pinnLoss: truth must be [B,5] like the soil estimate, got " + c10::str(truth.sizes()));
  const at::Tensor m = row_mask.defined() ? out.valid & row_mask.to(at::kBool) : out.valid;
  const at::Tensor mf = m.to(at::kDouble);
  const at::Tensor valid_frac = mf.mean(1);  // [B]: per-sample terms count once per valid step
  const at::Tensor wxz = at::tensor({w.w_xz[0], w.w_xz[1]}, at::kDouble);
  const at::Tensor Fm = force.to(at::kDouble);

  LossTerms t;
  const at::Tensor err = at::where(m.unsqueeze(-1), Fm - out.F, at::zeros_like(out.F));
  t.force_mae = (at::abs(err) * wxz).sum() / N;

  const at::Tensor r = Fm - out.F.detach();
  t.nll = nll2(r, out.Sigma_F, m, w.sigma_floor_n2).sum() / N;

  t.dngamma = (mf * at::abs(out.dNgamma_dbeta)).sum() / N;

  at::Tensor range = at::zeros({B}, at::kDouble);
  const at::Tensor th = out.theta_u.to(at::kDouble), lv = out.log_var.to(at::kDouble);
  for (int k = 0; k < kSoilCount; ++k) range = range + outside(th.select(1, k), kSoilRanges[k].lo, kSoilRanges[k].hi);
  range = range + outside(out.d_res.to(at::kDouble), -kDResMaxM, kDResMaxM);
  range = range + outside(out.beta_res.to(at::kDouble), -kBetaResMaxRad, kBetaResMaxRad);
  for (int k = 0; k < kLogVarCount; ++k) {
    const at::Tensor s = lv.select(1, k);
    range = range + at::relu(s - logVarHi(k)) + at::relu(logVarLo(k) - s);
  }
  t.range = (valid_frac * range).mean();

  const at::Tensor dr = out.d_res.to(at::kDouble), br = out.beta_res.to(at::kDouble);
  t.residual = (valid_frac * (dr * dr + br * br)).mean();

  t.force_res = (at::abs(out.F_r.to(at::kDouble)) * wxz).sum() / static_cast<double>(B);

  t.prior = spanDistance2(th, [](int k) { return 0.5 * (kSoilRanges[k].lo + kSoilRanges[k].hi); });
  if (truth.defined()) {
    const at::Tensor tt = truth.to(at::kDouble);
    t.soil = spanDistance2(th, [&](int k) { return tt.select(1, k); });
  } else {
    t.soil = at::zeros({}, at::kDouble);
  }

  t.total = w.lambda_F * t.force_mae + w.lambda_NLL * t.nll + w.lambda_beta * t.dngamma +
            w.lambda_range * t.range + w.lambda_res * t.residual + w.lambda_Fr * t.force_res;
  if (w.lambda_prior != 0) t.total = t.total + w.lambda_prior * t.prior;
  if (w.lambda_soil != 0) t.total = t.total + w.lambda_soil * t.soil;
  return t;
}

}  // namespace terramap::pinn

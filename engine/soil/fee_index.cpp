// The FEE index of one soil belief (soil/fee_index.hpp).
#include <terramap/soil/fee_index.hpp>

#include <cmath>

namespace terramap::soil {

FeeIndexValue feeIndexOf(const fee::Soil& mean, const fee::Soil& var, const FeeIndexConfig& cfg) {
  FeeIndexValue out;
  const fee::Geometry& g = cfg.geometry;
  const double beta = cfg.beta_min ? fee::betaMin(mean, g) : fee::betaNominal(mean);
  const fee::Result r = fee::evaluate(mean, g, beta);
  out.validity = std::isfinite(beta) ? r.validity : fee::Validity::NoAdmissibleBeta;
  if (out.validity != fee::Validity::Valid) return out;
  fee::Jacobian J = fee::jacobianF(mean, g, beta);
  // β is a function of φ and δ, not an independent parameter.
  if (cfg.beta_min) {
    const Eigen::Vector2d db = fee::betaMinGradient(mean, g);
    J.col(fee::kPhi) += db.x() * J.col(fee::kBeta);
    J.col(fee::kDelta) += db.y() * J.col(fee::kBeta);
  } else {
    J.col(fee::kPhi) += -0.5 * J.col(fee::kBeta);
  }
  Eigen::Matrix<double, 1, fee::kParamCount> j;
  if (cfg.horizontal) {
    out.index_n = r.F_N.x();
    j = J.row(0);
  } else {
    out.index_n = r.F_N.norm();
    if (!(out.index_n > 0.0)) return {};
    j = r.F_N.transpose() * J / out.index_n;
  }
  const double s = j(fee::kC) * j(fee::kC) * var.c_pa + j(fee::kPhi) * j(fee::kPhi) * var.phi_rad +
                   j(fee::kGamma) * j(fee::kGamma) * var.gamma_n_m3 + j(fee::kCa) * j(fee::kCa) * var.ca_pa +
                   j(fee::kDelta) * j(fee::kDelta) * var.delta_rad;
  out.var_n2 = s;
  if (!std::isfinite(out.index_n) || !std::isfinite(out.var_n2)) return {};
  return out;
}

}  // namespace terramap::soil

// Paper Eq. 7 on hand-built Jacobians whose null spaces are known.
#include "nullspace.hpp"

#include <ATen/Parallel.h>
#include <gtest/gtest.h>

namespace terramap::pinn {
namespace {

at::Tensor diag5(std::initializer_list<double> v) { return at::diag(at::tensor(std::vector<double>(v), at::kDouble)); }

/// A fixed 5x5 rotation (orthonormal Q of a seeded random matrix).
at::Tensor rotation() {
  at::manual_seed(5);
  return std::get<0>(at::linalg_qr(at::randn({5, 5}, at::kDouble)));
}

class Nullspace : public ::testing::Test {
 protected:
  void SetUp() override { at::set_num_threads(1); }
};

TEST_F(Nullspace, DropsSingularValuesBelowAbsoluteTolerance) {
  // Singular values 3000, 2000, 100, 0, 0 -> tolerance max(1500, 0.05 * 3000 = 150) = 1500 keeps
  // the first two: the null space is spanned by e3, e4, e5 (the 100 counts as null).
  at::Tensor J = at::zeros({4, 5}, at::kDouble);
  J[0][0] = 3000;
  J[1][1] = -2000;
  J[2][2] = 100;
  const at::Tensor Pn = nullspaceProjector(J);
  EXPECT_TRUE(at::allclose(Pn, diag5({0, 0, 1, 1, 1}), 0, 1e-12));
  const at::Tensor Sn = nullspaceCovariance(J, at::tensor({1.0, 2.0, 3.0, 4.0, 5.0}, at::kDouble));
  EXPECT_TRUE(at::allclose(Sn, diag5({0, 0, 3, 4, 5}), 0, 1e-12));
}

TEST_F(Nullspace, RelativeToleranceWinsForLargeJacobians) {
  // s = 1e6, 4e4: 0.05 * 1e6 = 5e4 > 1500, so 4e4 is dropped too.
  at::Tensor J = at::zeros({2, 5}, at::kDouble);
  J[0][1] = 1e6;
  J[1][3] = 4e4;
  EXPECT_TRUE(at::allclose(nullspaceProjector(J), diag5({1, 0, 1, 1, 1}), 0, 1e-12));
  // With r_tol = 0.01 the cut is 1e4 and 4e4 stays.
  EXPECT_TRUE(at::allclose(nullspaceProjector(J, {1500.0, 0.01}), diag5({1, 0, 1, 0, 1}), 0, 1e-12));
}

TEST_F(Nullspace, RotatedJacobianHasRotatedNullSpace) {
  // J2 = J R^T maps x to J (R^T x): its null space is R span(e3, e4, e5), so the projector
  // is R diag(0,0,1,1,1) R^T, and a full Sigma_a is multiplied from the left.
  at::Tensor J = at::zeros({4, 5}, at::kDouble);
  J[0][0] = 5000;
  J[1][1] = 2500;
  const at::Tensor R = rotation();
  const at::Tensor J2 = at::matmul(J, R.t());
  const at::Tensor want = at::matmul(at::matmul(R, diag5({0, 0, 1, 1, 1})), R.t());
  EXPECT_TRUE(at::allclose(nullspaceProjector(J2), want, 0, 1e-10));
  const at::Tensor Sa = at::matmul(at::matmul(R, diag5({1, 2, 3, 4, 5})), R.t());  // full, not diagonal
  EXPECT_TRUE(at::allclose(nullspaceCovariance(J2, Sa), at::matmul(want, Sa), 0, 1e-9));
  // A null vector really is one: J2 (R e5) = 0.
  EXPECT_LT(at::matmul(J2, R.select(1, 4)).abs().max().item<double>(), 1e-9);
}

TEST_F(Nullspace, InflatesWithMaximumAndBatches) {
  // Two samples of [2P = 4, 5]: the first sees only c and phi, the second everything but gamma.
  at::Tensor J = at::zeros({2, 4, 5}, at::kDouble);
  J[0][0][0] = 3000;
  J[0][1][1] = 2000;
  J[1][0][0] = 4000;
  J[1][1][1] = 4000;
  J[1][2][2] = 4000;
  J[1][3][3] = 4000;
  const at::Tensor Sn = nullspaceCovariance(J, at::full({5}, 9.0, at::kDouble));
  const at::Tensor var = at::tensor({1.0, 1.0, 1.0, 20.0, 1.0}, at::kDouble).expand({2, 5});
  const at::Tensor inflated = inflateVariances(var, Sn);
  // Sample 0: null {ca, delta, gamma} -> 9 where the network said 1; its 20 stays (max, not min).
  EXPECT_TRUE(at::allclose(inflated[0], at::tensor({1.0, 1.0, 9.0, 20.0, 9.0}, at::kDouble), 0, 1e-12));
  EXPECT_TRUE(at::allclose(inflated[1], at::tensor({1.0, 1.0, 1.0, 20.0, 9.0}, at::kDouble), 0, 1e-12));
}

TEST_F(Nullspace, SoilVariancesUseTheSoilColumnsOverTheWholeHorizon) {
  // Step 0 sees c (Fx) and phi (Fz); step 1 is an invalid step (zero rows); columns 5 and 6
  // (d_res, beta_res) are large but are not soil parameters and must not count.
  at::Tensor J = at::zeros({1, 2, 2, 7}, at::kDouble);
  J[0][0][0][0] = 3000;
  J[0][0][1][1] = 2000;
  J[0][0][0][5] = J[0][0][1][6] = J[0][1][0][5] = 1e6;
  const at::Tensor lv = at::zeros({1, 7}, at::kDouble);  // network variance 1 everywhere
  const at::Tensor v = soilVariances(J, lv, at::full({5}, 9.0, at::kDouble));
  EXPECT_TRUE(at::allclose(v, at::tensor({1.0, 1.0, 9.0, 9.0, 9.0}, at::kDouble).unsqueeze(0), 0, 1e-12));
  EXPECT_THROW(soilVariances(J.narrow(-1, 0, 4), lv, at::ones({5})), std::invalid_argument);
}

TEST_F(Nullspace, StackHorizonOrdersRowsByStep) {
  const at::Tensor Js = at::arange(2 * 3 * 2 * 5, at::kDouble).reshape({2, 3, 2, 5});
  const at::Tensor S = stackHorizon(Js);
  ASSERT_EQ(S.sizes(), (at::IntArrayRef{2, 6, 5}));
  EXPECT_TRUE(at::equal(S[1][3], Js[1][1][1]));  // row 2p+1 = Fz of step p
  EXPECT_THROW(stackHorizon(S), std::invalid_argument);
}

}  // namespace
}  // namespace terramap::pinn

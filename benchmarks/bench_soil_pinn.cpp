// Latency of one soil estimate, what the soil_pinn plugin spends per blade sweep
// (ALGORITHMS.md §F; goal: <= 1 ms on 1 thread, ensemble included, so it keeps up with the sweeps).
//
//   BM_SoilPinn: SoilEstimator::estimateFast(sample), the torch-free path the plugin runs
//     (terramap/soil/pinn_inference.hpp), for ONE sample with a deep ensemble of 5 members,
//     T = 30 history steps x 34 observation features, P = 10 horizon steps, encoder hidden
//     {128, 128}, physics layer at beta*. Each iteration is the whole estimate: observation
//     normalisation, five encoder passes (Eigen, float), the FEE and its Jacobian per horizon
//     step (terramap::fee), Eq. 7 nullspace inflation (one SVD of the stacked 20 x 5 Jacobian
//     per member), the ensemble's means and variances. Time per iteration = latency per estimate.
//   BM_SoilPinn_Libtorch: the same estimate through libtorch (SoilEstimator::estimate, what
//     training and `terramap eval-soil` use), one intra-op thread.
//   Counters: estimates_per_s (iterations per second of wall time), members (ensemble size),
//     valid_members (members whose FEE was valid at some horizon step for this sample: the
//     Jacobian and nullspace work is done for valid steps, so a sample the FEE rejects would
//     be cheaper and not representative; it must be 5).
// The weights are untrained (seeded), which costs the same as trained ones. The sample is a
// fixed synthetic one: seeded N(0, 1) observation features (the model's normalisation is mean
// 0, std 1) and a plausible cut (rho 1.45 rad, alpha 0.02 rad, w 1.8 m, d 0.08 m, Q 1500 N,
// v 0.5 m/s).
//
// soil_pinn is a MODULE library (not linkable): this program links its kernel library,
// soil_pinn_kernels, built with the module's flags.
#include "estimator.hpp"


#include <ATen/Parallel.h>
#include <torch/torch.h>
#include <benchmark/benchmark.h>

#include <random>

using namespace terramap;

namespace {

constexpr int kMembers = 5, kT = 30, kP = 10;

const pinn::SoilEstimator& estimator() {
  static const pinn::SoilEstimator e = [] {
    std::vector<pinn::PinnNet> members;
    for (int m = 0; m < kMembers; ++m)
      // The default model's settings (configs/train/pinn.yaml): beta*, penetration term.
      members.emplace_back(pinn::PinnConfig{kT, kP, soil::kObsFeatures, {128, 128}, 100 + m, pinn::BetaBase::Min, 0.025});
    return pinn::SoilEstimator(std::move(members), std::vector<float>(soil::kObsFeatures, 0.0f),
                               std::vector<float>(soil::kObsFeatures, 1.0f));
  }();
  return e;
}

soil::PinnSample sample() {
  soil::PinnSample s;
  s.T = kT;
  s.P = kP;
  std::mt19937 rng(7);
  std::normal_distribution<float> n01(0.0f, 1.0f);
  s.obs.resize(static_cast<std::size_t>(kT) * soil::kObsFeatures);
  for (float& v : s.obs) v = n01(rng);
  for (int p = 0; p < kP; ++p) {
    const float row[soil::kThetaK] = {1.45f, 0.02f, 1.8f, 0.08f + 0.002f * p, 1500.0f + 50.0f * p, 0.5f};
    s.theta_k.insert(s.theta_k.end(), row, row + soil::kThetaK);
  }
  s.force.assign(static_cast<std::size_t>(kP) * 2, 0.0f);
  return s;
}

template <bool kFast>
void runEstimates(benchmark::State& state) {
  at::set_num_threads(1);
  const pinn::SoilEstimator& est = estimator();
  const soil::PinnSample s = sample();
  int valid_members = 0;
  for (auto _ : state) {
    pinn::SoilEstimate e = kFast ? est.estimateFast(s) : est.estimate(s);
    valid_members = e.valid_members;
    benchmark::DoNotOptimize(e);
  }
  state.counters["estimates_per_s"] = benchmark::Counter(static_cast<double>(state.iterations()), benchmark::Counter::kIsRate);
  state.counters["members"] = kMembers;
  state.counters["valid_members"] = valid_members;
}

void BM_SoilPinn(benchmark::State& state) { runEstimates<true>(state); }
BENCHMARK(BM_SoilPinn)->Unit(benchmark::kMicrosecond)->UseRealTime();
void BM_SoilPinn_Libtorch(benchmark::State& state) { runEstimates<false>(state); }
BENCHMARK(BM_SoilPinn_Libtorch)->Unit(benchmark::kMicrosecond)->UseRealTime();

// Where BM_SoilPinn_Libtorch's time goes, per member (x5), same sample, same thread rule:
//   BM_SoilPinn_MemberForward: PinnNet::forward (encoder, heads, FEE layer, its autograd
//     Jacobian, Sigma_F) under NoGradGuard;
//   BM_SoilPinn_MemberFeeJacobian: feeJacobian alone on that member's inputs (B = 1, P = 10);
//   BM_SoilPinn_MemberNullspace: soilVariances (Eq. 7, one SVD of the stacked [2P x 5] Jacobian).
struct MemberInputs {
  at::Tensor obs, theta_k;
  pinn::PinnOutput out;
};
const MemberInputs& memberInputs() {
  static const MemberInputs m = [] {
    at::set_num_threads(1);
    torch::NoGradGuard no_grad;
    const soil::PinnSample s = sample();
    MemberInputs r;
    r.obs = estimator().normaliseObs(s.obs.data(), 1, kT);
    r.theta_k = at::from_blob(const_cast<float*>(s.theta_k.data()), {1, kP, 6}, at::kFloat).clone();
    pinn::PinnNet net = estimator().members().front();
    r.out = net->forward(r.obs, r.theta_k);
    return r;
  }();
  return m;
}

void BM_SoilPinn_MemberForward(benchmark::State& state) {
  at::set_num_threads(1);
  const MemberInputs& in = memberInputs();
  pinn::PinnNet net = estimator().members().front();
  torch::NoGradGuard no_grad;
  for (auto _ : state) benchmark::DoNotOptimize(net->forward(in.obs, in.theta_k));
}
BENCHMARK(BM_SoilPinn_MemberForward)->Unit(benchmark::kMicrosecond)->UseRealTime();

void BM_SoilPinn_MemberFeeJacobian(benchmark::State& state) {
  at::set_num_threads(1);
  const MemberInputs& in = memberInputs();
  torch::NoGradGuard no_grad;
  const at::Tensor soil = in.out.theta_u.to(at::kDouble);
  const at::Tensor k = in.theta_k.to(at::kDouble);
  const at::Tensor d = k.select(2, pinn::kKD) + in.out.d_res.to(at::kDouble).unsqueeze(1);
  for (auto _ : state)
    benchmark::DoNotOptimize(pinn::feeJacobian(soil, k.select(2, pinn::kKRho), k.select(2, pinn::kKAlpha),
                                               k.select(2, pinn::kKW), d, k.select(2, pinn::kKQ), in.out.beta));
}
BENCHMARK(BM_SoilPinn_MemberFeeJacobian)->Unit(benchmark::kMicrosecond)->UseRealTime();

void BM_SoilPinn_MemberNullspace(benchmark::State& state) {
  at::set_num_threads(1);
  const MemberInputs& in = memberInputs();
  torch::NoGradGuard no_grad;
  const at::Tensor sigma_a = pinn::defaultAmbiguityVariance();
  const at::Tensor lv = in.out.log_var.to(at::kDouble);
  for (auto _ : state) benchmark::DoNotOptimize(pinn::soilVariances(in.out.J, lv, sigma_a));
}
BENCHMARK(BM_SoilPinn_MemberNullspace)->Unit(benchmark::kMicrosecond)->UseRealTime();


}  // namespace

BENCHMARK_MAIN();

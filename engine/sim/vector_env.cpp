// N environments stepped together on the TBB pool, their results as batched arrays.
#include <terramap/core/error.hpp>
#include <terramap/sim/env.hpp>
#include <terramap/sim/world.hpp>

#include <tbb/partitioner.h>

#include <stdexcept>

namespace terramap::sim {

VectorEnv::VectorEnv(const Scenario& scenario, int n, VectorEnvOptions options) {
  if (n < 1) throw ConfigError("vector env: needs at least one environment (got " + std::to_string(n) + ")");
  if (options.threads < 1) throw ConfigError("vector env: threads must be >= 1 (got " + std::to_string(options.threads) + ")");
  // One initial terrain for all: each environment's simulator copies it at reset.
  auto kept = std::make_shared<const TruthTerrain>(buildTerrain(scenario.terrain));
  for (int k = 0; k < n; ++k) envs_.push_back(std::unique_ptr<Env>(new Env(scenario, options.env, kept)));
  exec_ = std::make_unique<Executor>(options.threads);
  affinity_ = std::make_unique<tbb::affinity_partitioner>();
  const Env& e0 = *envs_.front();
  for (std::size_t a = 0; a < e0.agentCount(); ++a) {
    action_width_ += e0.actionSize(a);
    obs_.emplace_back(static_cast<std::size_t>(n) * e0.observationSize(a), 0.0);
    rew_.emplace_back(static_cast<std::size_t>(n) * RewardTerms::names().size(), 0.0);
  }
  task_.assign(static_cast<std::size_t>(n) * TaskTerms::names().size(), 0.0);
  t_.assign(static_cast<std::size_t>(n), 0.0);
  terminated_.assign(static_cast<std::size_t>(n), 0);
  truncated_.assign(static_cast<std::size_t>(n), 0);
  last_.resize(static_cast<std::size_t>(n));
  final_.resize(static_cast<std::size_t>(n));
}

VectorEnv::~VectorEnv() = default;

void VectorEnv::gather(int k, const StepResult& r) {
  const std::size_t kk = static_cast<std::size_t>(k);
  for (std::size_t a = 0; a < obs_.size(); ++a) {
    const std::vector<double>& v = r.observation[a].vector;
    std::copy(v.begin(), v.end(), obs_[a].begin() + static_cast<std::ptrdiff_t>(kk * v.size()));
  }
  const std::vector<double> task = r.task.toVector();
  std::copy(task.begin(), task.end(), task_.begin() + static_cast<std::ptrdiff_t>(kk * task.size()));
  t_[kk] = r.info.t;
}

template <class F>
void VectorEnv::forEachEnv(F&& f) {
  if (exec_->threads() == 1 || exec_->backend() != Executor::Backend::kTbb || size() == 1) {
    exec_->forEach(size(), f);
    return;
  }
  // Each environment on the thread that stepped it last time where possible (TBB's affinity
  // partitioner replays the previous step's mapping): its terrain and machines stay in that
  // core's cache. Environments are independent, so the mapping changes no bit of the results.
  exec_->arena().execute([&] {
    tbb::parallel_for(
        tbb::blocked_range<int>(0, size(), 1),
        [&](const tbb::blocked_range<int>& r) {
          for (int k = r.begin(); k != r.end(); ++k) f(k);
        },
        *affinity_);
  });
}

void VectorEnv::reset(std::optional<std::uint64_t> seed) {
  forEachEnv([&](int k) {
    const std::size_t kk = static_cast<std::size_t>(k);
    last_[kk] = envs_[kk]->reset(seed ? std::optional<std::uint64_t>(*seed + kk) : std::nullopt);
    gather(k, last_[kk]);
    for (auto& r : rew_) std::fill_n(r.begin() + static_cast<std::ptrdiff_t>(kk * RewardTerms::names().size()),
                                     RewardTerms::names().size(), 0.0);
    terminated_[kk] = truncated_[kk] = 0;
  });
}

void VectorEnv::step(const double* actions, std::size_t n) {
  const std::size_t w = action_width_;
  if (n != w * envs_.size())
    throw std::invalid_argument("vector env: expected " + std::to_string(envs_.size()) + " x " + std::to_string(w) +
                                " lever values, got " + std::to_string(n));
  // Every action checked before any environment moves, so a bad one leaves the batch as it was.
  for (std::size_t k = 0; k < envs_.size(); ++k) {
    if (envs_[k]->needsReset()) throw std::logic_error("vector env: call reset() before step()");
    for (std::size_t i = 0; i < w; ++i) {
      const double v = actions[k * w + i];
      if (!(v >= -1.0 && v <= 1.0)) {
        std::size_t a = 0, j = i;
        while (j >= envs_[k]->actionSize(a)) j -= envs_[k]->actionSize(a++);
        throw std::invalid_argument("vector env: environment " + std::to_string(k) + ", agent " + envs_[k]->agentId(a) +
                                    " lever " + std::to_string(j) + " (" + envs_[k]->actionNames(a)[j] + ") = " +
                                    std::to_string(v) + ": levers lie in [-1, 1]");
      }
    }
  }
  forEachEnv([&](int k) {
    const std::size_t kk = static_cast<std::size_t>(k);
    Env& e = *envs_[kk];
    StepResult r = e.step(actions + kk * w, w);
    terminated_[kk] = r.terminated ? 1 : 0;
    truncated_[kk] = r.truncated ? 1 : 0;
    for (std::size_t a = 0; a < rew_.size(); ++a) {
      const std::vector<double> v = r.rewards[a].toVector();
      std::copy(v.begin(), v.end(), rew_[a].begin() + static_cast<std::ptrdiff_t>(kk * v.size()));
    }
    if (r.terminated || r.truncated) {
      // Autoreset in the same step: the next seed of this environment's own sequence.
      final_[kk] = std::move(r);
      last_[kk] = e.reset();
    } else {
      last_[kk] = std::move(r);
    }
    gather(k, last_[kk]);
  });
}

}  // namespace terramap::sim

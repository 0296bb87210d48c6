#pragma once
/// \file
/// What a soil estimator stage (soil_pinn, soil_fit) keeps between events: each machine's
/// observation history, and the sweeps it has taken from the bus and not yet estimated. A sweep's sample needs the observation at its last pose, which the simulator and
/// real drivers may deliver after that instant's BladePose, so a sweep waits until an
/// observation of its machine with stamp >= t1 has arrived (or the run ends). Header-only; used
/// on the stage's calling thread, as every ProcessContext use.
#include <terramap/plugin/plugin.hpp>
#include <terramap/plugin/records/sweep_record.hpp>
#include <terramap/soil/pinn_sample.hpp>

#include <map>
#include <memory>
#include <string>
#include <utility>
#include <vector>

namespace terramap::soil {

class PendingSweeps {
 public:
  /// A sweep published before the stage existed is not the stage's to estimate.
  void start(ProcessContext& ctx) {
    const Record* r = ctx.records().latest(SweepRecord::kType);
    last_sequence_ = r ? r->sequence : 0;
  }

  /// Every sweep since the last look, also when blade_sweep published several in one event or
  /// another stage ran between; only more than RecordBus::kHistory of them can be missed
  /// (counted as the drop `sweep_missed`). Counts `sweeps`.
  void collect(ProcessContext& ctx) {
    const RecordBus::Since got = ctx.records().since(SweepRecord::kType, last_sequence_);
    if (got.missed > 0) ctx.countDrop("sweep_missed", got.missed);
    for (const Record& r : got.records) {
      last_sequence_ = r.sequence;
      pending_.push_back(std::static_pointer_cast<const SweepRecord>(r.payload));
      ctx.addCounter("sweeps", 1);
    }
  }

  /// Calls estimate(sweep) for each sweep whose machine's history reached its t1 (every one when
  /// `all`), in the order they were published, and keeps the others.
  template <class Estimate>
  void drain(const std::map<std::string, ObservationHistory>& histories, bool all, Estimate&& estimate) {
    std::vector<std::shared_ptr<const SweepRecord>> keep;
    for (auto& rec : pending_) {
      bool ready = all;
      if (!ready) {
        auto it = histories.find(rec->machine_id);
        ready = it != histories.end() && !it->second.rows().empty() && it->second.rows().back().stamp >= rec->t1;
      }
      if (ready)
        estimate(*rec);
      else
        keep.push_back(std::move(rec));
    }
    pending_ = std::move(keep);
  }

  /// One event: an Observation joins its machine's history (kept to `capacity` rows; counted as
  /// `observations`, or dropped as `observation_out_of_order`), then new sweeps are taken and the
  /// ready ones estimated.
  template <class Estimate>
  void process(ProcessContext& ctx, const Event& event, std::size_t capacity, Estimate&& estimate) {
    if (const auto* o = std::get_if<Observation>(&event)) {
      auto it = histories_.try_emplace(o->machine_id, capacity).first;
      if (it->second.push(*o))
        ctx.addCounter("observations", 1);
      else
        ctx.countDrop("observation_out_of_order");
    }
    collect(ctx);
    if (!empty()) drain(histories_, false, estimate);
  }

  /// The end of the run: blade_sweep's finish() may have cut a last partial sweep; every sweep
  /// left is estimated with what the histories hold (counted as `sweeps_pending_at_finish`).
  template <class Estimate>
  void finish(ProcessContext& ctx, Estimate&& estimate) {
    collect(ctx);
    if (!empty()) ctx.addCounter("sweeps_pending_at_finish", static_cast<double>(size()));
    drain(histories_, true, estimate);
  }

  const std::map<std::string, ObservationHistory>& histories() const { return histories_; }
  std::size_t size() const { return pending_.size(); }
  bool empty() const { return pending_.empty(); }

 private:
  std::map<std::string, ObservationHistory> histories_;
  std::vector<std::shared_ptr<const SweepRecord>> pending_;
  long last_sequence_ = 0;
};

}  // namespace terramap::soil

#pragma once
/// \file
/// A pipeline Engine seen through the simulator evaluation's `sim::BlindMapper` interface
/// (`terramap eval` and the evaluation tests play a scenario through it). Header-only: it is
/// a thin forwarder. Not thread-safe (as the Engine's push()); the Engine must outlive it.
#include <terramap/pipeline/engine.hpp>
#include <terramap/sim/eval.hpp>

#include <memory>

namespace terramap {

class EngineBlindMapper : public sim::BlindMapper {
 public:
  explicit EngineBlindMapper(Engine& engine) : engine_(engine) {}
  LayeredMap& map() override { return engine_.mutableMap(); }
  void push(const Event& event) override { engine_.push(event); }
  /// The latest SweepRecord on the Engine's RecordBus (nullptr if none yet) and its sequence.
  std::shared_ptr<const SweepRecord> latestSweep(long* sequence) override {
    const Record* r = engine_.records().latest(SweepRecord::kType);
    if (!r) return nullptr;
    if (sequence) *sequence = r->sequence;
    return std::static_pointer_cast<const SweepRecord>(r->payload);
  }

 private:
  Engine& engine_;
};

}  // namespace terramap

// RecordBus: the latest record of a type, and since() for consumers that must see every record
// once although a publisher emits several in one event.
#include <terramap/plugin/plugin.hpp>

#include <gtest/gtest.h>

using namespace terramap;

namespace {

void publishInt(RecordBus& bus, const char* type, int v) {
  bus.publish<int>(type, 0.1 * v, std::make_shared<const int>(v));
}

int valueOf(const Record& r) { return *std::static_pointer_cast<const int>(r.payload); }

TEST(RecordBus, SinceGivesEveryRecordAfterASequenceInOrderPerType) {
  RecordBus bus;
  EXPECT_EQ(bus.latest("a"), nullptr);
  EXPECT_TRUE(bus.since("a", 0).records.empty());
  for (int v = 1; v <= 3; ++v) publishInt(bus, "a", 10 * v);
  publishInt(bus, "b", 7);
  ASSERT_NE(bus.latest("a"), nullptr);
  EXPECT_EQ(bus.latest("a")->sequence, 3);
  EXPECT_EQ(*bus.latestAs<int>("a"), 30);
  // Three published in one "event": a consumer that last saw sequence 1 gets 2 and 3.
  const RecordBus::Since s = bus.since("a", 1);
  ASSERT_EQ(s.records.size(), 2u);
  EXPECT_EQ(s.records[0].sequence, 2);
  EXPECT_EQ(valueOf(s.records[0]), 20);
  EXPECT_EQ(valueOf(s.records[1]), 30);
  EXPECT_DOUBLE_EQ(s.records[1].stamp, 3.0);
  EXPECT_EQ(s.missed, 0);
  EXPECT_TRUE(bus.since("a", 3).records.empty());
  EXPECT_EQ(bus.since("b", 0).records.size(), 1u);
  EXPECT_EQ(bus.since("b", 0).records[0].sequence, 1);
}

TEST(RecordBus, OnlyTheLastRecordsAreKeptAndTheRestAreCountedAsMissed) {
  RecordBus bus;
  const int n = static_cast<int>(RecordBus::kHistory) + 5;
  std::weak_ptr<const void> first;
  for (int v = 1; v <= n; ++v) {
    publishInt(bus, "a", v);
    if (v == 1) first = bus.latest("a")->payload;
  }
  EXPECT_TRUE(first.expired()) << "the oldest payload is released";
  const RecordBus::Since s = bus.since("a", 0);
  EXPECT_EQ(s.records.size(), RecordBus::kHistory);
  EXPECT_EQ(s.missed, 5);
  EXPECT_EQ(s.records.front().sequence, 6);
  EXPECT_EQ(s.records.back().sequence, n);
  EXPECT_EQ(bus.since("a", n - 2).missed, 0);
}

}  // namespace

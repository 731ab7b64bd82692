#include "common/transport/latest_slot.h"

#include <gtest/gtest.h>

#include "cutsim/v1/wire.pb.h"

namespace cutsim::transport {
namespace {

v1::HapticModel Model(uint64_t seq) {
  v1::HapticModel m;
  m.set_seq(seq);
  m.set_sim_time(0.001 * static_cast<double>(seq));
  return m;
}

TEST(LatestSlotTest, KeepsOnlyTheNewestBySequence) {
  LatestSlot<v1::HapticModel> slot;
  EXPECT_FALSE(slot.has_value());
  EXPECT_TRUE(slot.Offer(Model(3)));
  EXPECT_TRUE(slot.Offer(Model(5)));
  EXPECT_FALSE(slot.Offer(Model(4)));  // reordered: older than held
  EXPECT_FALSE(slot.Offer(Model(5)));  // duplicate
  EXPECT_TRUE(slot.Offer(Model(9)));   // gaps are fine
  EXPECT_EQ(slot.seq(), 9U);
  EXPECT_DOUBLE_EQ(slot.value().sim_time(), 0.009);
  EXPECT_EQ(slot.accepted(), 3U);
  EXPECT_EQ(slot.dropped_stale(), 1U);
  EXPECT_EQ(slot.dropped_duplicate(), 1U);
}

TEST(LatestSlotTest, FreshUntilConsumed) {
  LatestSlot<v1::HapticModel> slot;
  slot.Offer(Model(1));
  EXPECT_TRUE(slot.fresh());
  slot.MarkConsumed();
  EXPECT_FALSE(slot.fresh());
  slot.Offer(Model(1));  // duplicate does not refresh
  EXPECT_FALSE(slot.fresh());
  slot.Offer(Model(2));
  EXPECT_TRUE(slot.fresh());
}

TEST(LatestSlotTest, SenderRestartIsAcceptedBeyondTheWindow) {
  LatestSlot<v1::HapticModel> slot(/*restart_window=*/100);
  slot.Offer(Model(5000));
  EXPECT_FALSE(slot.Offer(Model(4950)));  // within the window: stale
  EXPECT_TRUE(slot.Offer(Model(1)));      // far below: a restarted sender
  EXPECT_EQ(slot.restarts(), 1U);
  EXPECT_EQ(slot.seq(), 1U);
  EXPECT_TRUE(slot.Offer(Model(2)));
}

TEST(LatestSlotTest, MoveOfferAndReset) {
  LatestSlot<v1::HapticModel> slot;
  v1::HapticModel m = Model(7);
  EXPECT_TRUE(slot.Offer(std::move(m)));
  EXPECT_EQ(slot.seq(), 7U);
  slot.Reset();
  EXPECT_FALSE(slot.has_value());
  EXPECT_TRUE(slot.Offer(Model(1)));  // after Reset anything is accepted
}

}  // namespace
}  // namespace cutsim::transport

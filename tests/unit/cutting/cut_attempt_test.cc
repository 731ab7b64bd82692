// Geometric criterion (method paper §3.1, Fig. 1): the attempt state machine.
#include <gtest/gtest.h>

#include "common/cutting/cut_attempt.h"

namespace cutsim::cutting {
namespace {

using Eigen::Vector3d;

// Surface vertices A = 0 at the origin, B = 1 one edge (h) along x, C = 2
// a twin of B (coincident copy from an earlier cut), D = 3 two edges along x.
constexpr double kH = 0.01;
VectorWorld Line() {
  return VectorWorld({Vector3d(0, 0, 0), Vector3d(kH, 0, 0), Vector3d(kH, 0, 0), Vector3d(2 * kH, 0, 0)});
}

Contact At(double x, int32_t closest) {
  Contact c;
  c.touching = true;
  c.point = Vector3d(x, 0.3 * kH, 0);  // on a facet next to the edge
  c.closest_node = closest;
  return c;
}

CutParams Params(double alpha = 0.4) {
  CutParams p;
  p.alpha = alpha;
  p.t0_timeout_frames = 5;
  return p;
}

TEST(CutAttempt, FirstContactSetsT0AndSameVertexIsNoAttempt) {
  const VectorWorld w = Line();
  CutAttemptTracker tr(Params());
  EXPECT_FALSE(tr.Update(At(0.1 * kH, 0), w).attempt);
  EXPECT_EQ(tr.anchor_node(), 0);
  EXPECT_FALSE(tr.Update(At(0.3 * kH, 0), w).attempt);  // condition 1 fails
  EXPECT_EQ(tr.anchor_node(), 0);
}

TEST(CutAttempt, SmallMovementInTheMiddleOfAFacetIsNotAnAttempt) {
  // The tool sits near the middle between A and B and moves by 2% of an
  // edge: the closest vertex flips from A to B (condition 1 holds) but C_p
  // is ≈ half an edge from B, outside r = α·d_v = 0.4 h.
  const VectorWorld w = Line();
  CutAttemptTracker tr(Params());
  EXPECT_FALSE(tr.Update(At(0.49 * kH, 0), w).attempt);
  const CutAttempt a = tr.Update(At(0.51 * kH, 1), w);
  EXPECT_FALSE(a.attempt);
  EXPECT_EQ(tr.anchor_node(), 0) << "t0 is kept: the tool may still go on to cut";
  // Going on close to B enters N(v_c(t)) = ball(x_B, 0.4 h): an attempt.
  const CutAttempt b = tr.Update(At(0.8 * kH, 1), w);
  ASSERT_TRUE(b.attempt);
  EXPECT_EQ(b.v0, 0);
  EXPECT_EQ(b.v1, 1);
  EXPECT_NEAR(b.radius, 0.4 * kH, 1e-15);
  EXPECT_EQ(b.cp0, At(0.49 * kH, 0).point) << "C_p(t0) is the first contact";
  EXPECT_EQ(b.cp, At(0.8 * kH, 1).point);
}

TEST(CutAttempt, NeighbourhoodIsCentredOnTheCurrentClosestVertex) {
  const VectorWorld w = Line();
  CutAttemptTracker tr(Params(0.5));
  tr.Update(At(0.0, 0), w);
  // |C_p − x_B| = sqrt(0.45² + 0.3²) h ≈ 0.54 h > 0.5 h: outside.
  EXPECT_FALSE(tr.Update(At(0.55 * kH, 1), w).attempt);
  // |C_p − x_B| = sqrt(0.3² + 0.3²) h ≈ 0.42 h ≤ 0.5 h: inside.
  EXPECT_TRUE(tr.Update(At(0.7 * kH, 1), w).attempt);
}

TEST(CutAttempt, T0ResetsAfterAnExecutedCutSoTheCutProgresses) {
  const VectorWorld w = Line();
  CutAttemptTracker tr(Params());
  tr.Update(At(0.0, 0), w);
  ASSERT_TRUE(tr.Update(At(0.9 * kH, 1), w).attempt);
  tr.OnCutExecuted();
  EXPECT_EQ(tr.anchor_node(), 1);
  EXPECT_EQ(tr.anchor_point(), At(0.9 * kH, 1).point);
  EXPECT_FALSE(tr.Update(At(1.1 * kH, 1), w).attempt);
  const CutAttempt a = tr.Update(At(1.9 * kH, 3), w);
  ASSERT_TRUE(a.attempt);
  EXPECT_EQ(a.v0, 1);
  EXPECT_EQ(a.v1, 3);
  EXPECT_EQ(a.cp0, At(0.9 * kH, 1).point);
}

TEST(CutAttempt, AttemptNotExecutedKeepsT0) {
  // The criterion said no (stress too low): the next frames stay attempts.
  const VectorWorld w = Line();
  CutAttemptTracker tr(Params());
  tr.Update(At(0.0, 0), w);
  EXPECT_TRUE(tr.Update(At(0.9 * kH, 1), w).attempt);
  EXPECT_TRUE(tr.Update(At(0.95 * kH, 1), w).attempt);
  EXPECT_EQ(tr.anchor_node(), 0);
}

TEST(CutAttempt, ContactLossResetsT0) {
  const VectorWorld w = Line();
  CutAttemptTracker tr(Params());
  tr.Update(At(0.0, 0), w);
  Contact lost;
  EXPECT_FALSE(tr.Update(lost, w).attempt);
  EXPECT_FALSE(tr.has_anchor());
  // The next touch is a new t0, even right at another vertex.
  EXPECT_FALSE(tr.Update(At(0.95 * kH, 1), w).attempt);
  EXPECT_EQ(tr.anchor_node(), 1);
}

TEST(CutAttempt, WanderingOutsideTheNeighbourhoodTooLongReanchors) {
  const VectorWorld w = Line();
  CutAttemptTracker tr(Params());  // timeout 5 frames
  tr.Update(At(0.45 * kH, 0), w);
  for (int i = 0; i < 4; ++i) EXPECT_FALSE(tr.Update(At(0.52 * kH, 1), w).attempt);
  EXPECT_EQ(tr.anchor_node(), 0);
  EXPECT_FALSE(tr.Update(At(0.52 * kH, 1), w).attempt);
  EXPECT_EQ(tr.anchor_node(), 1) << "5th frame outside N: t0 := t";
  EXPECT_EQ(tr.anchor_point(), At(0.52 * kH, 1).point);
}

TEST(CutAttempt, TwinVerticesAreNeverAnAttempt) {
  // d_v = 0 between coincident copies, so r = 0.
  const VectorWorld w = Line();
  CutAttemptTracker tr(Params());
  tr.Update(At(kH, 1), w);
  EXPECT_FALSE(tr.Update(At(kH, 2), w).attempt);
}

}  // namespace
}  // namespace cutsim::cutting

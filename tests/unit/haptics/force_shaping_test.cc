#include "common/haptics/force_shaping.h"

#include <cmath>

#include <gtest/gtest.h>

#include "tests/unit/haptics/test_models.h"

namespace cutsim::haptics {
namespace {

using testing::ContactModel;

constexpr double kTangentialRatio = 1.0;

TEST(BufferModelTest, EqualsF0AtX0AndIsLinearInDisplacement) {
  LocalModel m = ContactModel(1, Eigen::Vector3d(0.01, -0.02, 0.005), Eigen::Vector3d(0.3, -0.2, 3.0));
  m.stiffness << 900, 50, 20,  //
      50, 700, -30,           //
      20, -30, 1200;
  const BoundedModel b = BoundModel(m, DeviceLimits{.max_force = 100.0, .max_stiffness = 1e4});
  const Eigen::Vector3d zero = Eigen::Vector3d::Zero();
  EXPECT_LT((EvaluateBufferModel(b, m.x0, zero, 100.0, kTangentialRatio) - m.f0).norm(), 1e-15);

  // Inside the region where no bound is active, F − f0 = −K(x − x0): linear.
  const Eigen::Vector3d d(0.3e-3, -0.2e-3, -0.5e-3);  // m, into the tissue
  const Eigen::Vector3d df1 = EvaluateBufferModel(b, m.x0 + d, zero, 100.0, kTangentialRatio) - m.f0;
  const Eigen::Vector3d df2 = EvaluateBufferModel(b, m.x0 + 2.5 * d, zero, 100.0, kTangentialRatio) - m.f0;
  EXPECT_LT((df2 - 2.5 * df1).norm(), 1e-12);
  EXPECT_LT((df1 + m.stiffness * d).norm(), 1e-12);
  // Pushing in (along −n) raises the outward force: K = −∂f/∂x is a spring.
  EXPECT_GT(df1.z(), 0.0);
  // Damping opposes the velocity.
  ASSERT_TRUE(b.contact);
  BoundedModel damped = b;
  damped.damping = 5.0;
  const Eigen::Vector3d v(0.0, 0.0, -0.01);
  EXPECT_NEAR(EvaluateBufferModel(damped, m.x0, v, 100.0, kTangentialRatio).z() - m.f0.z(), 0.05, 1e-12);
}

TEST(BufferModelTest, NoContactRendersNothing) {
  const BoundedModel none = BoundModel(LocalModel{}, DeviceLimits{});
  EXPECT_EQ(EvaluateBufferModel(none, Eigen::Vector3d(0, 0, -1), Eigen::Vector3d(1, 2, 3), 8.0, 1.0),
            Eigen::Vector3d::Zero());
}

TEST(UnilateralTest, TissueOnlyPushes) {
  const Eigen::Vector3d n = Eigen::Vector3d(1, 2, 2).normalized();
  // Pulling (F·n < 0) is removed entirely, including any tangential part.
  EXPECT_EQ(ApplyUnilateral(-2.0 * n + Eigen::Vector3d(2, -1, 0) / 3.0, n, 1.0), Eigen::Vector3d::Zero());
  // Pushing passes unchanged while inside the tangential bound.
  const Eigen::Vector3d t = Eigen::Vector3d(2, -1, 0).normalized();  // ⟂ n
  const Eigen::Vector3d push = 3.0 * n + 1.0 * t;
  EXPECT_LT((ApplyUnilateral(push, n, 1.0) - push).norm(), 1e-15);
  // Tangential part bounded by ratio · F_n.
  const Eigen::Vector3d sideways = 0.5 * n + 4.0 * t;
  const Eigen::Vector3d clamped = ApplyUnilateral(sideways, n, 1.0);
  EXPECT_NEAR(clamped.dot(n), 0.5, 1e-15);
  EXPECT_NEAR((clamped - clamped.dot(n) * n).norm(), 0.5, 1e-15);

  // As the tool leaves the surface the force goes to zero continuously.
  LocalModel m = ContactModel(1, Eigen::Vector3d::Zero(), Eigen::Vector3d(0, 0, 1.0), 1000.0);
  m.stiffness(0, 0) = 500.0;
  const BoundedModel b = BoundModel(m, DeviceLimits{});
  double previous = 1e9;
  for (double z = -1e-3; z <= 2e-3; z += 1e-5) {
    const Eigen::Vector3d x(0.2e-3, 0.0, z);
    const Eigen::Vector3d f = EvaluateBufferModel(b, x, Eigen::Vector3d::Zero(), 8.0, 1.0);
    EXPECT_GE(f.z(), 0.0);
    EXPECT_LE(f.norm(), previous + 1e-12);  // monotone release, no step
    if (z > 1e-3 + 1e-9) {
      EXPECT_EQ(f, Eigen::Vector3d::Zero());  // beyond the zero of f0 − K(x − x0)
    }
    previous = f.norm();
  }
}

TEST(DeviceBoundsTest, ForceMagnitudeAndStiffnessAreBounded) {
  const DeviceLimits limits{.max_force = 4.0, .max_stiffness = 1000.0, .max_damping = 3.0};
  LocalModel m = ContactModel(1, Eigen::Vector3d::Zero(), Eigen::Vector3d(0, 0, 0.5), 0.0);
  m.stiffness = Eigen::Vector3d(500.0, 4000.0, 2000.0).asDiagonal();
  m.damping = 10.0;
  const BoundedModel b = BoundModel(m, limits);
  EXPECT_NEAR(LargestEigenvalue(b.stiffness), 1000.0, 1e-9);
  EXPECT_NEAR(b.stiffness_scale, 0.25, 1e-15);
  EXPECT_NEAR(b.stiffness(0, 0), 125.0, 1e-9);  // shape kept
  EXPECT_EQ(b.damping, 3.0);
  for (double depth : {1e-4, 1e-3, 1e-2, 1.0}) {
    const Eigen::Vector3d f =
        EvaluateBufferModel(b, Eigen::Vector3d(0, 0, -depth), Eigen::Vector3d::Zero(), 4.0, 1.0);
    EXPECT_LE(f.norm(), 4.0 + 1e-12);
    EXPECT_NEAR(f.z(), std::min(0.5 + 500.0 * depth, 4.0), 1e-9);  // 2000 N/m scaled to 500
  }
  EXPECT_EQ(ClampMagnitude(Eigen::Vector3d(3, 4, 0), 2.5), Eigen::Vector3d(1.5, 2.0, 0));
  EXPECT_EQ(ClampMagnitude(Eigen::Vector3d(3, 4, 0), 5.0), Eigen::Vector3d(3, 4, 0));
}

TEST(LimitStepTest, NeverStepsMoreThanAllowed) {
  const Eigen::Vector3d from(1, 1, 1);
  EXPECT_EQ(LimitStep(from, Eigen::Vector3d(1.1, 1, 1), 0.5), Eigen::Vector3d(1.1, 1, 1));
  const Eigen::Vector3d to = LimitStep(from, Eigen::Vector3d(1, 1, 11), 0.5);
  EXPECT_NEAR((to - from).norm(), 0.5, 1e-15);
  EXPECT_NEAR(to.z(), 1.5, 1e-15);
  EXPECT_EQ(LimitStep(from, Eigen::Vector3d(5, 5, 5), 0.0), from);
}

TEST(CutDecayTest, MatchesMethodPaperEquation13) {
  const Eigen::Vector3d fc(0, 1, 2);
  EXPECT_EQ(CutDecayForce(fc, 40.0, 0.0), fc);
  // Seed: F_c e^(−ξ_iter I) with ξ_iter = ξ/1000 at 1 kHz.
  for (int iteration : {1, 10, 100}) {
    EXPECT_NEAR((CutDecayForce(fc, 40.0, iteration * 1e-3) - fc * std::exp(-0.040 * iteration)).norm(),
                0.0, 1e-15);
  }
}

TEST(RaisedCosineTest, SmoothMonotoneRamp) {
  EXPECT_EQ(RaisedCosine(-1.0), 0.0);
  EXPECT_EQ(RaisedCosine(0.0), 0.0);
  EXPECT_NEAR(RaisedCosine(0.5), 0.5, 1e-15);
  EXPECT_EQ(RaisedCosine(1.0), 1.0);
  EXPECT_EQ(RaisedCosine(2.0), 1.0);
  for (double p = 0.0; p < 1.0; p += 0.01) EXPECT_LE(RaisedCosine(p), RaisedCosine(p + 0.01));
}

}  // namespace
}  // namespace cutsim::haptics

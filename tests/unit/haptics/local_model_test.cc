#include "common/haptics/local_model.h"

#include <cmath>
#include <limits>

#include <Eigen/Eigenvalues>
#include <gtest/gtest.h>

#include "tests/unit/haptics/test_models.h"

namespace cutsim::haptics {
namespace {

using testing::ContactModel;

constexpr double kNaN = std::numeric_limits<double>::quiet_NaN();
constexpr double kInf = std::numeric_limits<double>::infinity();

LocalModel GoodModel() {
  LocalModel m = ContactModel(1, Eigen::Vector3d(0.01, 0.02, -0.001), Eigen::Vector3d(0, 0, 2.0), 800.0);
  m.stiffness(0, 0) = 100.0;  // some tangential stiffness too
  m.damping = 2.0;
  m.valid_for = 0.03;
  m.cut.decay_per_second = 40.0;
  return m;
}

TEST(ValidateTest, AcceptsAWellFormedModel) {
  EXPECT_EQ(Validate(GoodModel()), ModelIssue::kOk);
  EXPECT_EQ(Validate(LocalModel{}), ModelIssue::kOk);  // no contact
}

TEST(ValidateTest, RejectsNonFiniteValuesInEveryField) {
  for (double bad : {kNaN, kInf, -kInf}) {
    auto expect_non_finite = [&](auto&& mutate) {
      LocalModel m = GoodModel();
      mutate(m);
      EXPECT_EQ(Validate(m), ModelIssue::kNonFinite);
    };
    expect_non_finite([&](LocalModel& m) { m.sim_time = bad; });
    expect_non_finite([&](LocalModel& m) { m.x0.y() = bad; });
    expect_non_finite([&](LocalModel& m) { m.normal.x() = bad; });
    expect_non_finite([&](LocalModel& m) { m.f0.z() = bad; });
    expect_non_finite([&](LocalModel& m) { m.stiffness(1, 2) = bad; });
    expect_non_finite([&](LocalModel& m) { m.damping = bad; });
    expect_non_finite([&](LocalModel& m) { m.valid_for = bad; });
    expect_non_finite([&](LocalModel& m) { m.cut.decay_per_second = bad; });
    // Finiteness is checked even when the model says "no contact".
    expect_non_finite([&](LocalModel& m) {
      m.contact = false;
      m.f0.x() = bad;
    });
  }
}

TEST(ValidateTest, RejectsNonUnitNormalInContactOnly) {
  LocalModel m = GoodModel();
  m.normal = Eigen::Vector3d(0, 0, 1.01);
  EXPECT_EQ(Validate(m), ModelIssue::kNonUnitNormal);
  m.normal = Eigen::Vector3d::Zero();
  EXPECT_EQ(Validate(m), ModelIssue::kNonUnitNormal);
  m.contact = false;
  EXPECT_EQ(Validate(m), ModelIssue::kOk);
  m = GoodModel();
  m.normal = Eigen::Vector3d(0, 0, 1.0 + 1e-9);  // round-off passes
  EXPECT_EQ(Validate(m), ModelIssue::kOk);
}

TEST(ValidateTest, RejectsAsymmetricAndIndefiniteStiffness) {
  LocalModel m = GoodModel();
  m.stiffness(0, 1) = 50.0;  // K(1, 0) stays 0
  EXPECT_EQ(Validate(m), ModelIssue::kAsymmetricStiffness);
  m = GoodModel();
  m.stiffness(0, 1) = m.stiffness(1, 0) = 1e-5;  // ‖K − Kᵀ‖ = 0: fine
  EXPECT_EQ(Validate(m), ModelIssue::kOk);
  m = GoodModel();
  m.stiffness(1, 1) = -10.0;  // would pull the tool in
  EXPECT_EQ(Validate(m), ModelIssue::kNegativeStiffness);
  m = GoodModel();
  m.stiffness(1, 1) = -1e-7;  // within tolerance of PSD
  EXPECT_EQ(Validate(m), ModelIssue::kOk);
}

TEST(ValidateTest, RejectsAbsurdMagnitudesAndNegativeParameters) {
  auto issue_of = [](auto&& mutate) {
    LocalModel m = GoodModel();
    mutate(m);
    return Validate(m);
  };
  EXPECT_EQ(issue_of([](LocalModel& m) { m.x0.x() = 1e3; }), ModelIssue::kAbsurdMagnitude);
  EXPECT_EQ(issue_of([](LocalModel& m) { m.f0.z() = 1e6; }), ModelIssue::kAbsurdMagnitude);
  EXPECT_EQ(issue_of([](LocalModel& m) { m.stiffness *= 1e6; }), ModelIssue::kAbsurdMagnitude);
  EXPECT_EQ(issue_of([](LocalModel& m) { m.damping = 1e9; }), ModelIssue::kAbsurdMagnitude);
  EXPECT_EQ(issue_of([](LocalModel& m) { m.valid_for = 1e9; }), ModelIssue::kAbsurdMagnitude);
  EXPECT_EQ(issue_of([](LocalModel& m) { m.cut.decay_per_second = 1e9; }), ModelIssue::kAbsurdMagnitude);
  EXPECT_EQ(issue_of([](LocalModel& m) { m.damping = -1.0; }), ModelIssue::kNegativeParameter);
  EXPECT_EQ(issue_of([](LocalModel& m) { m.valid_for = -1.0; }), ModelIssue::kNegativeParameter);
  EXPECT_EQ(issue_of([](LocalModel& m) { m.cut.decay_per_second = -1.0; }), ModelIssue::kNegativeParameter);
}

TEST(ValidateTest, EveryIssueHasAName) {
  for (int i = 0; i < kModelIssueCount; ++i) {
    EXPECT_NE(ToString(static_cast<ModelIssue>(i)), "unknown") << i;
  }
}

TEST(SymmetricPsdPartTest, SymmetrisesAndClampsNegativeEigenvalues) {
  Eigen::Matrix3d k;
  k << 1000, 200, 0,  //
      -100, -300, 50,  //
      10, 30, 500;
  const Eigen::Matrix3d psd = SymmetricPsdPart(k);
  EXPECT_EQ((psd - psd.transpose()).norm(), 0.0);
  Eigen::SelfAdjointEigenSolver<Eigen::Matrix3d> solver(psd);
  EXPECT_GE(solver.eigenvalues().minCoeff(), -1e-9);
  // Unchanged on the non-negative eigenspace of the symmetric part.
  Eigen::SelfAdjointEigenSolver<Eigen::Matrix3d> sym(0.5 * (k + k.transpose()));
  for (int i = 0; i < 3; ++i) {
    const Eigen::Vector3d q = sym.eigenvectors().col(i);
    const double expected = std::max(sym.eigenvalues()(i), 0.0);
    EXPECT_NEAR(q.dot(psd * q), expected, 1e-9 * k.norm());
  }
  // A PSD matrix is a fixed point.
  const Eigen::Matrix3d again = SymmetricPsdPart(psd);
  EXPECT_LT((again - psd).norm(), 1e-12 * psd.norm());
  Eigen::Matrix3d bad = k;
  bad(0, 0) = kNaN;
  EXPECT_EQ(SymmetricPsdPart(bad), Eigen::Matrix3d::Zero());
}

TEST(BuildLocalModelTest, FillsFieldsAndProducesAValidModel) {
  ModelHeader header{.seq = 42, .stamp_ns = 123, .sim_time = 1.5, .valid_for = 0.04,
                     .cut = {.cuts = 3, .cutting = true, .decay_per_second = 25.0},
                     .topology_version = 7};
  Eigen::Matrix3d k;  // asymmetric, indefinite FEM-like stiffness
  k << 900, 120, 0,  //
      80, -40, 0,    //
      0, 0, 1500;
  ContactLinearisation contact{.contact = true,
                               .x0 = Eigen::Vector3d(0.01, 0, 0.02),
                               .normal = Eigen::Vector3d(0, 0, 2.0),  // not unit
                               .f0 = Eigen::Vector3d(0, 0, 1.2),
                               .stiffness = k,
                               .damping = -1.0};
  const LocalModel m = BuildLocalModel(header, contact);
  EXPECT_EQ(Validate(m), ModelIssue::kOk);
  EXPECT_TRUE(m.contact);
  EXPECT_EQ(m.seq, 42u);
  EXPECT_EQ(m.stamp_ns, 123);
  EXPECT_EQ(m.sim_time, 1.5);
  EXPECT_EQ(m.valid_for, 0.04);
  EXPECT_EQ(m.cut.cuts, 3u);
  EXPECT_TRUE(m.cut.cutting);
  EXPECT_EQ(m.cut.decay_per_second, 25.0);
  EXPECT_EQ(m.topology_version, 7u);
  EXPECT_EQ(m.x0, contact.x0);
  EXPECT_EQ(m.f0, contact.f0);
  EXPECT_NEAR((m.normal - Eigen::Vector3d::UnitZ()).norm(), 0.0, 1e-15);
  EXPECT_EQ(m.damping, 0.0);
  EXPECT_EQ((m.stiffness - m.stiffness.transpose()).norm(), 0.0);
  EXPECT_NEAR(m.stiffness(2, 2), 1500.0, 1e-9);
}

TEST(BuildLocalModelTest, DegenerateContactBecomesNoContact) {
  ModelHeader header{.seq = 9};
  ContactLinearisation zero_normal{.contact = true, .normal = Eigen::Vector3d::Zero()};
  EXPECT_FALSE(BuildLocalModel(header, zero_normal).contact);
  ContactLinearisation nan_force{.contact = true, .f0 = Eigen::Vector3d(kNaN, 0, 0)};
  const LocalModel m = BuildLocalModel(header, nan_force);
  EXPECT_FALSE(m.contact);
  EXPECT_EQ(m.seq, 9u);
  EXPECT_EQ(Validate(m), ModelIssue::kOk);
  ContactLinearisation absurd{.contact = true, .f0 = Eigen::Vector3d(0, 0, 1e9)};
  EXPECT_FALSE(BuildLocalModel(header, absurd).contact);
  EXPECT_EQ(Validate(BuildLocalModel(header, absurd)), ModelIssue::kOk);
}

}  // namespace
}  // namespace cutsim::haptics

#include "common/core/units.h"

#include <gtest/gtest.h>

namespace cutsim::units {
namespace {

TEST(UnitsTest, LameRoundTripsThroughYoungPoisson) {
  // The method paper's ligament: λ = 140 kPa, μ = 11 kPa.
  const Lame ligament{140e3, 11e3};
  const double E = YoungFromLame(ligament);
  const double nu = PoissonFromLame(ligament);
  const Lame back = LameFromYoungPoisson(E, nu);
  EXPECT_NEAR(back.lambda, ligament.lambda, 1e-9 * ligament.lambda);
  EXPECT_NEAR(back.mu, ligament.mu, 1e-9 * ligament.mu);
  EXPECT_GT(nu, 0.0);
  EXPECT_LT(nu, 0.5);
}

TEST(UnitsTest, KnownValues) {
  const Lame l = LameFromYoungPoisson(1.0, 0.25);
  EXPECT_DOUBLE_EQ(l.mu, 0.4);
  EXPECT_DOUBLE_EQ(l.lambda, 0.4);
  EXPECT_DOUBLE_EQ(kMillimetre * 1000.0, 1.0);
}

}  // namespace
}  // namespace cutsim::units

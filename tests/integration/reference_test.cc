// The stored CalculiX references (bench/reference/) as the accuracy bench
// reads them: complete, converged, consistent with beam theory and with the
// closed-form compressed block, and the loader's errors name file, line and
// field. The rerun of CalculiX itself is the ctest
// reference.CalculixReproducesTheStoredReference (run_calculix.py --check).
#include <cmath>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <stdexcept>
#include <string>

#include <gtest/gtest.h>

#include "bench/reference/reference_data.h"

namespace cutsim::bench::reference {
namespace {

const std::string kDir = std::string(CUTSIM_SOURCE_DIR) + "/bench/reference/";

// scenes/beam.pbtxt: 100 × 20 × 20 mm, E = 1 MPa, ρ = 1000 kg/m³, g = 9.81 m/s².
constexpr double kLength = 0.1, kSection = 0.02, kYoung = 1.0e6, kDensity = 1000.0, kGravity = 9.81;

double TimoshenkoTip(double poisson) {
  const double area = kSection * kSection, inertia = std::pow(kSection, 4) / 12.0;
  const double q = kDensity * kGravity * area;  // N/m
  const double shear = kYoung / (2.0 * (1.0 + poisson));
  const double bending = q * std::pow(kLength, 4) / (8.0 * kYoung * inertia);
  const double shearing = q * kLength * kLength / (2.0 * (5.0 / 6.0) * shear * area);  // shear factor 5/6
  return -(bending + shearing);
}

TEST(ReferenceDataTest, BeamSweepCoversThePoissonRatiosConverged) {
  const auto sweep = LoadBeamReference(kDir + "beam_nu_sweep.csv");
  ASSERT_EQ(sweep.size(), 4u);
  for (const double nu : {0.3, 0.45, 0.49, 0.499}) {
    const auto r = FindBeamReference(sweep, nu);
    ASSERT_TRUE(r.has_value()) << "nu = " << nu;
    EXPECT_LT(r->tip_m, 0.0) << "nu = " << nu;
    EXPECT_LE(r->tip_uncertainty_m, 0.01 * std::abs(r->tip_m)) << "nu = " << nu;
    // The bench's node-mean definition and the face-area mean of the smooth
    // field describe the same end face.
    EXPECT_NEAR(r->tip_5x5_mean_m, r->tip_m, 1e-3 * std::abs(r->tip_m)) << "nu = " << nu;
  }
  EXPECT_FALSE(FindBeamReference(sweep, 0.25).has_value());
}

TEST(ReferenceDataTest, BeamAtPoissonPointThreeAgreesWithTimoshenko) {
  const auto r = FindBeamReference(LoadBeamReference(kDir + "beam_nu_sweep.csv"), 0.3);
  ASSERT_TRUE(r.has_value());
  EXPECT_NEAR(r->tip_m, TimoshenkoTip(0.3), 0.03 * std::abs(TimoshenkoTip(0.3)));
}

TEST(ReferenceDataTest, SlipBlockMatchesTheHomogeneousStVKSolution) {
  const auto blocks = LoadBlockReference(kDir + "compressed_block.csv");
  const BlockReference* slip = nullptr;
  for (const auto& b : blocks) {
    if (b.variant == "slip") slip = &b;
  }
  ASSERT_NE(slip, nullptr);
  // Uniaxial StVK: lateral Green strain −ν·E_zz, J = λ_x²·λ_z, P_zz = λ_z·E·E_zz.
  constexpr double kNu = 0.499, kE = 1.0e4, kSide = 0.02, kStretch = 0.8;
  const double green_z = 0.5 * (kStretch * kStretch - 1.0);
  const double volume_ratio = (1.0 - 2.0 * kNu * green_z) * kStretch;
  EXPECT_NEAR(slip->volume_change, volume_ratio - 1.0, 1e-5);
  EXPECT_NEAR(slip->top_force_z_n, kStretch * kE * green_z * kSide * kSide, 1e-5);
}

class BadCsvTest : public ::testing::Test {
 protected:
  std::string Write(const std::string& text) {
    std::ofstream(path_) << text;
    return path_;
  }
  void TearDown() override { std::filesystem::remove(path_); }
  std::string path_ = (std::filesystem::temp_directory_path() /
                       ("cutsim_reference_test_" + std::to_string(::testing::UnitTest::GetInstance()->random_seed()) +
                        ".csv"))
                          .string();
};

std::string ErrorOf(const std::string& path) {
  try {
    LoadBeamReference(path);
  } catch (const std::runtime_error& e) {
    return e.what();
  }
  return "";
}

TEST_F(BadCsvTest, ErrorsNameTheFileLineAndField) {
  const std::string header = std::string(internal::kBeamHeader) + "\n";
  const std::string bad_number = Write("# comment\n" + header + "0.3,C3D10,-0.00375,1e-6,oops,1e-6\n");
  EXPECT_NE(ErrorOf(bad_number).find(bad_number + ":3: field tip_5x5_mean_m"), std::string::npos)
      << ErrorOf(bad_number);
  const std::string short_row = Write(header + "0.3,C3D10,-0.00375\n");
  EXPECT_NE(ErrorOf(short_row).find(":2: expected 6 fields, got 3"), std::string::npos) << ErrorOf(short_row);
  const std::string wrong_header = Write("nu,tip\n0.3,1\n");
  EXPECT_NE(ErrorOf(wrong_header).find(":1: header must be"), std::string::npos) << ErrorOf(wrong_header);
  EXPECT_NE(ErrorOf(path_ + ".missing").find("cannot open"), std::string::npos);
}

}  // namespace
}  // namespace cutsim::bench::reference

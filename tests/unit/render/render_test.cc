#include <gtest/gtest.h>

#include <algorithm>
#include <utility>
#include <cmath>
#include <cstdint>
#include <cstdlib>
#include <string>
#include <vector>

#include "common/core/error.h"
#include "common/render/camera.h"
#include "common/render/image.h"
#include "common/render/palette.h"
#include "common/render/surface_renderer.h"
#include "cube_fixture.h"

namespace cutsim::render {
namespace {

using testing::CubePositions;
using testing::CubeTriangles;

constexpr int kWidth = 320;
constexpr int kHeight = 240;

class RenderTest : public ::testing::Test {
 protected:
  mesh::Positions positions_ = CubePositions();
  mesh::Triangles triangles_ = CubeTriangles();
  Camera camera_ = FrameBoundingBox(BoundingBox(positions_), kWidth, kHeight);
  SurfaceRenderer renderer_;

  Image RenderCube(std::span<const uint8_t> opened = {}, const RenderOptions& options = {}) {
    return renderer_.Render(
        camera_, SurfaceInput{.positions = positions_, .triangles = triangles_, .opened = opened},
        options);
  }
};

TEST_F(RenderTest, CubeCoversPartOfTheFrame) {
  const Image image = RenderCube();
  ASSERT_TRUE(image.valid());
  EXPECT_EQ(image.width, kWidth);
  EXPECT_EQ(image.height, kHeight);
  const double coverage = NonBackgroundFraction(image);
  EXPECT_GE(coverage, 0.05);
  EXPECT_LT(coverage, 1.0);
  // The corners of a framed scene are background.
  EXPECT_TRUE(IsBackground(image.pixel(0, 0)[0], image.pixel(0, 0)[1], image.pixel(0, 0)[2]));
}

TEST_F(RenderTest, CubeIsShadedTissueWithSeveralDistinctFaceColours) {
  const Image image = RenderCube();
  std::vector<uint32_t> colours;
  for (size_t i = 0; i < image.rgba.size(); i += 4) {
    const uint8_t* p = image.rgba.data() + i;
    if (IsBackground(p[0], p[1], p[2])) continue;
    // Every surface pixel is the tissue hue, only darker or brighter.
    const HueSaturation hs = ToHueSaturation(p[0], p[1], p[2]);
    ASSERT_NEAR(hs.hue_deg, ToHueSaturation(kTissueRgb[0], kTissueRgb[1], kTissueRgb[2]).hue_deg,
                3.0);
    const uint32_t key = (uint32_t{p[0]} << 16) | (uint32_t{p[1]} << 8) | p[2];
    if (std::find(colours.begin(), colours.end(), key) == colours.end()) colours.push_back(key);
  }
  // Three visible faces, flat shaded: three distinct colours.
  EXPECT_EQ(colours.size(), 3U);
}

TEST_F(RenderTest, NoOpenedFacesMeansNoCutColour) {
  EXPECT_EQ(CountCutFacePixels(RenderCube()), 0);
  const std::vector<uint8_t> none(12, 0);
  EXPECT_EQ(CountCutFacePixels(RenderCube(none)), 0);
}

TEST_F(RenderTest, OpenedFacesShowInTheCutColour) {
  std::vector<uint8_t> opened(12, 0);
  opened[2] = opened[3] = 1;  // the top face, visible from the default view
  const Image image = RenderCube(opened);
  const int64_t cut_pixels = CountCutFacePixels(image);
  EXPECT_GT(static_cast<double>(cut_pixels), 0.005 * kWidth * kHeight);
  // Only the two opened triangles changed colour.
  const Image intact = RenderCube();
  EXPECT_NEAR(NonBackgroundFraction(image), NonBackgroundFraction(intact), 1e-9);
}

TEST_F(RenderTest, OpenedFacesSeenFromBehindAreLitToo) {
  // Looking into the cube from inside: every face is seen from its back.
  camera_.eye = {0.5, 0.2, 0.5};
  camera_.target = {0.5, 1.0, 0.4};
  std::vector<uint8_t> opened(12, 0);
  opened[6] = opened[7] = 1;  // +y face, straight ahead
  const Image image = RenderCube(opened);
  EXPECT_GT(CountCutFacePixels(image), kWidth * kHeight / 10);
}

TEST_F(RenderTest, ImageChangesWhenTheCameraMoves) {
  const Image before = RenderCube();
  camera_ = FrameBoundingBox(BoundingBox(positions_), kWidth, kHeight, {-1.0, 1.3, 0.7});
  const Image after = RenderCube();
  EXPECT_GT(MeanAbsoluteDifference(before, after), 1.0);
  EXPECT_EQ(MeanAbsoluteDifference(before, before), 0.0);
}

TEST_F(RenderTest, RowsAreTopDown) {
  // Aim below the cube: it must appear in the upper half of the image.
  camera_.eye = {0.5, -4.0, 0.5};
  camera_.target = {0.5, 0.0, -0.6};
  camera_.up = {0.0, 0.0, 1.0};
  const Image image = RenderCube();
  int64_t top = 0;
  int64_t bottom = 0;
  for (int y = 0; y < kHeight; ++y) {
    for (int x = 0; x < kWidth; ++x) {
      const uint8_t* p = image.pixel(x, y);
      if (!IsBackground(p[0], p[1], p[2])) (y < kHeight / 2 ? top : bottom) += 1;
    }
  }
  EXPECT_GT(top, 0);
  EXPECT_GT(top, 5 * bottom);
}

TEST_F(RenderTest, StressColouringUsesTheColourMapAndNeverTheCutColour) {
  std::vector<double> stress(8);
  for (int i = 0; i < 8; ++i) stress[static_cast<size_t>(i)] = positions_(i, 2) * 1e4;  // Pa
  const Image image = renderer_.Render(
      camera_,
      SurfaceInput{.positions = positions_, .triangles = triangles_, .vertex_scalar = stress},
      RenderOptions{.scalar_range = ScalarRange{0.0, 1e4}});
  EXPECT_EQ(CountCutFacePixels(image), 0);
  EXPECT_GE(NonBackgroundFraction(image), 0.05);
  EXPECT_GT(MeanAbsoluteDifference(image, RenderCube()), 1.0);
}

TEST(PaletteTest, ColourMapLitAtAnyLevelIsNeitherCutNorBackground) {
  for (int i = 0; i <= 200; ++i) {
    const Rgb c = StressColour(i / 200.0);
    for (double k = kMinLight; k <= 1.0; k += 0.01) {
      auto lit = [k](uint8_t v) { return static_cast<uint8_t>(std::lround(k * v)); };
      const uint8_t r = lit(c[0]), g = lit(c[1]), b = lit(c[2]);
      ASSERT_FALSE(IsCutFaceColour(r, g, b)) << "t=" << i / 200.0 << " k=" << k;
      ASSERT_FALSE(IsBackground(r, g, b)) << "t=" << i / 200.0 << " k=" << k;
    }
  }
}

TEST(PaletteTest, BaseColoursClassifyAtEveryLightLevel) {
  for (double k = kMinLight; k <= 1.0; k += 0.01) {
    auto lit = [k](const Rgb& c, int i) {
      return static_cast<uint8_t>(std::lround(k * c[static_cast<size_t>(i)]));
    };
    EXPECT_TRUE(IsCutFaceColour(lit(kCutFaceRgb, 0), lit(kCutFaceRgb, 1), lit(kCutFaceRgb, 2)))
        << k;
    EXPECT_FALSE(IsCutFaceColour(lit(kTissueRgb, 0), lit(kTissueRgb, 1), lit(kTissueRgb, 2))) << k;
    EXPECT_FALSE(IsCutFaceColour(lit(kToolRgb, 0), lit(kToolRgb, 1), lit(kToolRgb, 2))) << k;
    EXPECT_FALSE(IsCutFaceColour(lit(kHandleRgb, 0), lit(kHandleRgb, 1), lit(kHandleRgb, 2))) << k;
    EXPECT_FALSE(IsBackground(lit(kHandleRgb, 0), lit(kHandleRgb, 1), lit(kHandleRgb, 2))) << k;
    EXPECT_FALSE(IsBackground(lit(kCutFaceRgb, 0), lit(kCutFaceRgb, 1), lit(kCutFaceRgb, 2))) << k;
    EXPECT_FALSE(IsBackground(lit(kTissueRgb, 0), lit(kTissueRgb, 1), lit(kTissueRgb, 2))) << k;
    EXPECT_FALSE(IsBackground(lit(kToolRgb, 0), lit(kToolRgb, 1), lit(kToolRgb, 2))) << k;
    EXPECT_TRUE(IsForceColour(lit(kForceRgb, 0), lit(kForceRgb, 1), lit(kForceRgb, 2))) << k;
    for (const Rgb& other : {kTissueRgb, kCutFaceRgb, kToolRgb, kHandleRgb, kBackgroundRgb}) {
      EXPECT_FALSE(IsForceColour(lit(other, 0), lit(other, 1), lit(other, 2))) << k;
    }
  }
  for (int i = 0; i <= 200; ++i) {
    const Rgb c = StressColour(i / 200.0);
    EXPECT_FALSE(IsForceColour(c[0], c[1], c[2])) << "stress map at " << i / 200.0;
  }
  EXPECT_TRUE(IsBackground(kBackgroundRgb[0], kBackgroundRgb[1], kBackgroundRgb[2]));
  EXPECT_FALSE(IsCutFaceColour(kBackgroundRgb[0], kBackgroundRgb[1], kBackgroundRgb[2]));
}

TEST_F(RenderTest, ToolAddsSteelPixels) {
  const Image without = RenderCube();
  RenderOptions options;
  const Eigen::Vector3d tip(0.5, 0.5, 1.02);
  const Eigen::Vector3d handle(0.5, -0.2, 1.6);
  options.tool = ToolSegment{
      .pose = {tip, (handle - tip).normalized()}, .length = (handle - tip).norm(), .radius = 0.03};
  const Image with = RenderCube({}, options);
  EXPECT_GT(NonBackgroundFraction(with), NonBackgroundFraction(without));
  EXPECT_EQ(CountCutFacePixels(with), 0);
}

/// Pixels of the scalpel: the blade (kToolRgb) and the handle (kHandleRgb),
/// told apart by saturation (lighting scales all channels alike), with the
/// mean image row of each.
struct ScalpelPixels {
  int blade = 0, handle = 0;
  double blade_row = 0, handle_row = 0;
};
ScalpelPixels CountScalpel(const Image& image) {
  const double blade_sat = ToHueSaturation(kToolRgb[0], kToolRgb[1], kToolRgb[2]).saturation;
  const double handle_sat = ToHueSaturation(kHandleRgb[0], kHandleRgb[1], kHandleRgb[2]).saturation;
  ScalpelPixels s;
  for (int y = 0; y < image.height; ++y) {
    for (int x = 0; x < image.width; ++x) {
      const uint8_t* p = image.pixel(x, y);
      if (IsBackground(p[0], p[1], p[2]) || std::max({p[0], p[1], p[2]}) < 40) continue;
      const HueSaturation hs = ToHueSaturation(p[0], p[1], p[2]);
      if (hs.hue_deg < 200 || hs.hue_deg > 240) continue;
      if (std::abs(hs.saturation - blade_sat) < 0.04) {
        ++s.blade;
        s.blade_row += y;
      } else if (std::abs(hs.saturation - handle_sat) < 0.04) {
        ++s.handle;
        s.handle_row += y;
      }
    }
  }
  if (s.blade > 0) s.blade_row /= s.blade;
  if (s.handle > 0) s.handle_row /= s.handle;
  return s;
}

TEST_F(RenderTest, ScalpelIsAFlatBladeBelowItsHandle) {
  // A vertical scalpel in front of the cube, tip down, seen from the side.
  camera_.eye = {0.5, -4.0, 0.5};
  camera_.target = {0.5, 0.0, 0.5};
  camera_.up = {0.0, 0.0, 1.0};
  RenderOptions options;
  options.tool = ToolSegment{.pose = {.tip = {0.5, -0.3, -0.2}, .blade_dir = {0, 0, 1}}, .length = 0.5};
  const Image face_on = RenderCube({}, options);
  if (const char* dir = std::getenv("CUTSIM_RENDER_DUMP")) WritePng(std::string(dir) + "/scalpel.png", face_on);
  const ScalpelPixels s = CountScalpel(face_on);
  EXPECT_GT(s.blade, 200);
  EXPECT_GT(s.handle, 200);
  // Oriented by the blade direction: the blade at the bottom (the tip), the
  // handle above it.
  EXPECT_GT(s.blade_row, s.handle_row + 20);
  // Flat: turned edge-on (its edge toward the camera) the blade nearly vanishes.
  options.tool->edge_dir = {0, -1, 0};
  const ScalpelPixels edge_on = CountScalpel(RenderCube({}, options));
  EXPECT_LT(5 * edge_on.blade, s.blade);
  EXPECT_GT(edge_on.handle, 0);
  EXPECT_EQ(CountCutFacePixels(face_on), 0);
}

/// Pixels of the force colour in the image (left part: the gauge; rest: the arrow).
std::pair<int, int> CountForcePixels(const Image& image) {
  int gauge = 0, arrow = 0;
  for (int y = 0; y < image.height; ++y) {
    for (int x = 0; x < image.width; ++x) {
      const uint8_t* p = image.pixel(x, y);
      if (!IsForceColour(p[0], p[1], p[2])) continue;
      (x < image.width / 10 ? gauge : arrow) += 1;
    }
  }
  return {gauge, arrow};
}

TEST_F(RenderTest, ForceShowsAsAnArrowAndAGaugeThatGrowsWithIt) {
  const auto [gauge0, arrow0] = CountForcePixels(RenderCube());
  EXPECT_EQ(gauge0 + arrow0, 0) << "nothing on the tissue, tool or background is force-coloured";
  RenderOptions options;
  options.force = ForceOverlay{.at = Eigen::Vector3d(0.5, 0.5, 1.02), .force = Eigen::Vector3d(0.3, 0, 0.5),
                               .full_scale = 2.0};
  const auto [gauge1, arrow1] = CountForcePixels(RenderCube({}, options));
  options.force->force *= 3.0;
  const auto [gauge2, arrow2] = CountForcePixels(RenderCube({}, options));
  EXPECT_GT(gauge1, 0);
  EXPECT_GT(arrow1, 0);
  EXPECT_GT(gauge2, 2 * gauge1);  // the bar fills in proportion
  EXPECT_GT(arrow2, arrow1);
  options.force->force.setZero();
  const auto [gauge3, arrow3] = CountForcePixels(RenderCube({}, options));
  EXPECT_EQ(gauge3 + arrow3, 0) << "no force: an empty gauge frame and no arrow";
  options.force->full_scale = 0.0;
  EXPECT_THROW((void)RenderCube({}, options), InputError);
}

TEST_F(RenderTest, BadInputThrowsNamingTheField) {
  mesh::Triangles bad = triangles_;
  bad(5, 1) = 8;
  try {
    (void)renderer_.Render(camera_, SurfaceInput{.positions = positions_, .triangles = bad});
    FAIL() << "expected InputError";
  } catch (const InputError& e) {
    EXPECT_EQ(e.source().field, "render.triangles");
  }
  const std::vector<uint8_t> short_flags(11, 0);
  EXPECT_THROW((void)RenderCube(short_flags), InputError);
  camera_.fov_deg = 0.0;
  EXPECT_THROW((void)RenderCube(), InputError);
}

TEST_F(RenderTest, EmptySurfaceRendersBackground) {
  const mesh::Positions none_p(0, 3);
  const mesh::Triangles none_t(0, 3);
  const Image image =
      renderer_.Render(camera_, SurfaceInput{.positions = none_p, .triangles = none_t});
  EXPECT_EQ(NonBackgroundFraction(image), 0.0);
}

TEST_F(RenderTest, FarFromTheOriginStillRenders) {
  // Float vertex arrays are relative to the scene centre, so 10 km offsets
  // at millimetre scale keep their precision.
  positions_ = positions_ * 1e-3;
  positions_.rowwise() += Eigen::RowVector3d(1e4, -2e4, 5e3);
  camera_ = FrameBoundingBox(BoundingBox(positions_), kWidth, kHeight);
  const double coverage = NonBackgroundFraction(RenderCube());
  EXPECT_GE(coverage, 0.05);
}

TEST(CameraTest, FramingKeepsTheBoxInsideTheImage) {
  const Eigen::AlignedBox3d box(Eigen::Vector3d(-2, -1, 0), Eigen::Vector3d(3, 1, 0.5));
  for (const auto& [w, h] : {std::pair{640, 480}, std::pair{200, 600}}) {
    const Camera camera = FrameBoundingBox(box, w, h);
    ValidateCamera(camera);
    const Eigen::Matrix4d pv = camera.ProjectionMatrix(0.1, 100.0) * camera.ViewMatrix();
    for (int corner = 0; corner < 8; ++corner) {
      const Eigen::Vector3d c = box.corner(static_cast<Eigen::AlignedBox3d::CornerType>(corner));
      const Eigen::Vector4d clip = pv * c.homogeneous();
      EXPECT_LT(std::abs(clip.x() / clip.w()), 1.0);
      EXPECT_LT(std::abs(clip.y() / clip.w()), 1.0);
    }
    // The centre lands at the image centre.
    const Eigen::Vector4d centre = pv * box.center().homogeneous();
    EXPECT_NEAR(centre.x() / centre.w(), 0.0, 1e-12);
    EXPECT_NEAR(centre.y() / centre.w(), 0.0, 1e-12);
  }
  // Looking straight down still has a valid up vector.
  ValidateCamera(FrameBoundingBox(box, 64, 64, {0, 0, 1}));
}

}  // namespace
}  // namespace cutsim::render

#include "common/render/image.h"

#include <gtest/gtest.h>
#include <unistd.h>

#include <filesystem>
#include <fstream>
#include <string>

#include "common/core/error.h"
#include "common/render/camera.h"
#include "common/render/surface_renderer.h"
#include "cube_fixture.h"

namespace cutsim::render {
namespace {

namespace fs = std::filesystem;

/// A fresh directory under the system temp dir, removed afterwards.
class ImageTest : public ::testing::Test {
 protected:
  void SetUp() override {
    dir_ = fs::temp_directory_path() /
           ("cutsim_render_" + std::to_string(::getpid()) + "_" +
            ::testing::UnitTest::GetInstance()->current_test_info()->name());
    fs::remove_all(dir_);
    fs::create_directories(dir_);
  }
  void TearDown() override { fs::remove_all(dir_); }

  static Image Gradient(int width, int height) {
    Image image{width, height, std::vector<uint8_t>(static_cast<size_t>(width * height) * 4)};
    for (int y = 0; y < height; ++y) {
      for (int x = 0; x < width; ++x) {
        uint8_t* p = image.rgba.data() + 4 * (y * width + x);
        p[0] = static_cast<uint8_t>(x * 7);
        p[1] = static_cast<uint8_t>(y * 13);
        p[2] = static_cast<uint8_t>(x ^ y);
        p[3] = static_cast<uint8_t>(255 - x);
      }
    }
    return image;
  }

  fs::path dir_;
};

TEST_F(ImageTest, PngRoundTripIsExact) {
  const Image image = Gradient(37, 21);  // odd sizes: no row padding assumptions
  const fs::path path = dir_ / "gradient.png";
  WritePng(path, image);
  EXPECT_FALSE(fs::exists(dir_ / "gradient.png.tmp"));
  const Image back = ReadPng(path);
  EXPECT_EQ(back.width, image.width);
  EXPECT_EQ(back.height, image.height);
  EXPECT_EQ(back.rgba, image.rgba);
}

TEST_F(ImageTest, RenderedFrameRoundTripsThroughPng) {
  const mesh::Positions p = testing::CubePositions();
  const mesh::Triangles t = testing::CubeTriangles();
  std::vector<uint8_t> opened(12, 0);
  opened[2] = opened[3] = 1;
  SurfaceRenderer renderer;
  const Image frame = renderer.Render(FrameBoundingBox(BoundingBox(p), 200, 150),
                                      {.positions = p, .triangles = t, .opened = opened});
  const fs::path path = dir_ / "cube.png";
  WritePng(path, frame);
  const Image back = ReadPng(path);
  EXPECT_EQ(MeanAbsoluteDifference(frame, back), 0.0);
  EXPECT_EQ(back.rgba, frame.rgba);
  EXPECT_EQ(CountCutFacePixels(back), CountCutFacePixels(frame));
}

TEST_F(ImageTest, UnwritablePathThrowsInputErrorNamingThePath) {
  const fs::path path = dir_ / "no_such_dir" / "frame.png";
  try {
    WritePng(path, Gradient(4, 4));
    FAIL() << "expected InputError";
  } catch (const InputError& e) {
    EXPECT_EQ(e.source().file, path.string());
    EXPECT_NE(std::string(e.what()).find(path.string()), std::string::npos) << e.what();
  }
}

TEST_F(ImageTest, FailedWriteLeavesTheGoodFileAlone) {
  const fs::path path = dir_ / "good.png";
  const Image good = Gradient(8, 8);
  WritePng(path, good);
  Image broken = Gradient(8, 8);
  broken.rgba.resize(10);  // invalid: not width·height·4 bytes
  EXPECT_THROW(WritePng(path, broken), InputError);
  // A directory squatting on the temporary name makes the write itself fail.
  fs::create_directory(dir_ / "good.png.tmp");
  EXPECT_THROW(WritePng(path, Gradient(8, 8)), InputError);
  EXPECT_EQ(ReadPng(path).rgba, good.rgba);
}

TEST_F(ImageTest, ReadingAMissingOrCorruptFileThrowsInputError) {
  EXPECT_THROW((void)ReadPng(dir_ / "missing.png"), InputError);
  const fs::path junk = dir_ / "junk.png";
  std::ofstream(junk) << "not a png";
  try {
    (void)ReadPng(junk);
    FAIL() << "expected InputError";
  } catch (const InputError& e) {
    EXPECT_EQ(e.source().file, junk.string());
  }
}

TEST(ImageMetricsTest, FractionsCountsAndDifferences) {
  Image a{2, 2, std::vector<uint8_t>(16, 0)};
  for (int i = 0; i < 4; ++i) {  // all background
    a.rgba[4 * i] = 30, a.rgba[4 * i + 1] = 34, a.rgba[4 * i + 2] = 44, a.rgba[4 * i + 3] = 255;
  }
  EXPECT_EQ(NonBackgroundFraction(a), 0.0);
  Image b = a;
  b.rgba[0] = 235, b.rgba[1] = 185, b.rgba[2] = 30;  // one cut-face pixel
  EXPECT_EQ(NonBackgroundFraction(b), 0.25);
  EXPECT_EQ(CountCutFacePixels(b), 1);
  EXPECT_NEAR(MeanAbsoluteDifference(a, b), (205.0 + 151.0 + 14.0) / 12.0, 1e-12);
  const Image c{1, 1, std::vector<uint8_t>(4, 0)};
  EXPECT_THROW((void)MeanAbsoluteDifference(a, c), std::invalid_argument);
}

}  // namespace
}  // namespace cutsim::render

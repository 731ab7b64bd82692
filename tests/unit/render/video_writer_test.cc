#include "common/render/video_writer.h"

#include <gtest/gtest.h>
#include <unistd.h>

#include <cmath>
#include <cstdlib>
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

fs::path TestDir(const std::string& name) {
  const fs::path dir =
      fs::temp_directory_path() / ("cutsim_video_" + std::to_string(::getpid()) + "_" + name);
  fs::remove_all(dir);
  fs::create_directories(dir);
  return dir;
}

/// Puts a fake `ffmpeg` (a shell script) first on PATH for the test's
/// lifetime, so the pipe, rename and error paths are tested without ffmpeg.
class FakeFfmpeg {
 public:
  /// `body` runs after `last` holds the last argument (the output file).
  FakeFfmpeg(const std::string& name, const std::string& body) : dir_(TestDir(name)) {
    const fs::path script = dir_ / "ffmpeg";
    std::ofstream(script)
        << "#!/bin/sh\n"
           "if [ \"$2\" = \"-encoders\" ]; then echo ' V..... mpeg4 MPEG-4'; exit 0; fi\n"
           "for a; do last=$a; done\n"
        << body << "\n";
    fs::permissions(script, fs::perms::owner_all);
    const char* old = std::getenv("PATH");
    old_path_ = old != nullptr ? old : "";
    ::setenv("PATH", (dir_.string() + ":" + old_path_).c_str(), 1);
  }
  ~FakeFfmpeg() {
    ::setenv("PATH", old_path_.c_str(), 1);
    fs::remove_all(dir_);
  }
  FakeFfmpeg(const FakeFfmpeg&) = delete;
  FakeFfmpeg& operator=(const FakeFfmpeg&) = delete;

 private:
  fs::path dir_;
  std::string old_path_;
};

Image Blank(int width, int height) {
  return Image{width, height, std::vector<uint8_t>(static_cast<size_t>(width * height) * 4, 7)};
}

TEST(FfmpegVideoWriterTest, PipesRawFramesAndRenamesWhenDone) {
  const FakeFfmpeg fake("fake_ok", "cat > \"$last\"");
  ASSERT_TRUE(FfmpegVideoWriter::Available());
  const fs::path dir = TestDir("fake_out");
  const fs::path path = dir / "clip.mkv";
  {
    FfmpegVideoWriter writer(path, 32, 16, 30.0);
    for (int i = 0; i < 5; ++i) writer.WriteFrame(Blank(32, 16));
    writer.Close();
    writer.Close();  // idempotent
  }
  ASSERT_TRUE(fs::exists(path));
  EXPECT_EQ(fs::file_size(path), 5U * 32U * 16U * 4U);  // the raw frames, byte for byte
  EXPECT_FALSE(fs::exists(dir / "clip.tmp.mkv"));
  {
    FfmpegVideoWriter writer(path, 32, 16, 30.0);  // destructor commits too
    writer.WriteFrame(Blank(32, 16));
  }
  EXPECT_EQ(fs::file_size(path), 32U * 16U * 4U);
  fs::remove_all(dir);
}

TEST(FfmpegVideoWriterTest, DeadFfmpegGivesAnErrorNotSigpipeAndKeepsTheOldFile) {
  const FakeFfmpeg fake("fake_dead", "exit 3");
  const fs::path dir = TestDir("fake_dead_out");
  const fs::path path = dir / "keep.mp4";
  { std::ofstream(path) << "previous good video"; }
  {
    FfmpegVideoWriter writer(path, 512, 512, 25.0);  // 1 MiB frames overflow the pipe
    try {
      for (int i = 0; i < 4; ++i) writer.WriteFrame(Blank(512, 512));
      writer.Close();
      FAIL() << "expected InputError";
    } catch (const InputError& e) {
      EXPECT_EQ(e.source().file, path.string());
    }
  }
  EXPECT_EQ(fs::file_size(path), std::string("previous good video").size());
  EXPECT_FALSE(fs::exists(dir / "keep.tmp.mp4"));
  fs::remove_all(dir);
}

TEST(FfmpegVideoWriterTest, UnwindingDiscardsThePartialVideo) {
  const FakeFfmpeg fake("fake_unwind", "cat > \"$last\"");
  const fs::path dir = TestDir("fake_unwind_out");
  const fs::path path = dir / "partial.mp4";
  try {
    FfmpegVideoWriter writer(path, 8, 8, 25.0);
    writer.WriteFrame(Blank(8, 8));
    throw std::runtime_error("simulation failed");
  } catch (const std::runtime_error&) {
  }
  EXPECT_FALSE(fs::exists(path));
  EXPECT_FALSE(fs::exists(dir / "partial.tmp.mp4"));
  fs::remove_all(dir);
}

TEST(FfmpegVideoWriterTest, BadArgumentsThrowBeforeStartingFfmpeg) {
  EXPECT_THROW(FfmpegVideoWriter("/tmp/no_extension", 64, 64, 25.0), InputError);
  EXPECT_THROW(FfmpegVideoWriter("/tmp/video.mp4", 0, 64, 25.0), InputError);
  EXPECT_THROW(FfmpegVideoWriter("/tmp/video.mp4", 64, 64, 0.0), InputError);
}

TEST(FfmpegVideoWriterTest, EncodesAnOrbitOfTheCube) {
  if (!FfmpegVideoWriter::Available()) GTEST_SKIP() << "no ffmpeg executable on PATH";
  const fs::path dir = TestDir("orbit");
  const fs::path path = dir / "orbit.mp4";
  const mesh::Positions p = testing::CubePositions();
  const mesh::Triangles t = testing::CubeTriangles();
  SurfaceRenderer renderer;
  {
    FfmpegVideoWriter writer(path, 161, 121, 25.0);  // odd size: padded for yuv420p
    for (int i = 0; i < 12; ++i) {
      const double angle = 0.3 * i;
      const Camera camera =
          FrameBoundingBox(BoundingBox(p), 161, 121, {std::cos(angle), std::sin(angle), 0.8});
      writer.WriteFrame(renderer.Render(camera, {.positions = p, .triangles = t}));
    }
    EXPECT_THROW(writer.WriteFrame(Image{10, 10, std::vector<uint8_t>(400, 0)}), InputError);
    EXPECT_FALSE(fs::exists(path));  // only the temporary exists while encoding
    writer.Close();
    EXPECT_EQ(writer.frames_written(), 12);
  }
  ASSERT_TRUE(fs::exists(path));
  EXPECT_GT(fs::file_size(path), 1000U);
  EXPECT_FALSE(fs::exists(dir / "orbit.tmp.mp4"));
  fs::remove_all(dir);
}

TEST(FfmpegVideoWriterTest, FailedEncodeNeverReplacesAGoodVideo) {
  if (!FfmpegVideoWriter::Available()) GTEST_SKIP() << "no ffmpeg executable on PATH";
  const fs::path dir = TestDir("failed");
  // ffmpeg has no muxer for this extension, so the encode fails at Close.
  const fs::path path = dir / "keep.nosuchformat";
  { std::ofstream(path) << "previous good video"; }
  {
    FfmpegVideoWriter writer(path, 64, 64, 25.0);
    try {
      writer.WriteFrame(Image{64, 64, std::vector<uint8_t>(64 * 64 * 4, 128)});
    } catch (const InputError&) {
      // ffmpeg may already have exited: the failure shows here or at Close.
    }
    EXPECT_THROW(writer.Close(), InputError);
  }
  EXPECT_EQ(fs::file_size(path), std::string("previous good video").size());
  fs::remove_all(dir);
}

}  // namespace
}  // namespace cutsim::render

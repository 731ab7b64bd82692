#include "common/haptics/tool_path.h"

#include <filesystem>
#include <string>
#include <unistd.h>

#include <gtest/gtest.h>

#include "common/core/error.h"

namespace cutsim::haptics {
namespace {

const char* kPath = R"(# a path
0.0  0 0 0.03   0 0 2
1.0  0.1 0 0.03 0 0 1   # trailing comment

2.0  0.1 0.1 0.03 0 1 0
)";

TEST(ToolPathTest, ParsesAndNormalises) {
  const ToolPath p = ToolPath::Parse(kPath, "p.path");
  ASSERT_EQ(p.keyframes().size(), 3u);
  EXPECT_DOUBLE_EQ(p.keyframes()[0].pose.blade_dir.norm(), 1.0);
  EXPECT_DOUBLE_EQ(p.end_time(), 2.0);
}

TEST(ToolPathTest, SampleInterpolatesAndClamps) {
  const ToolPath p = ToolPath::Parse(kPath, "p.path");
  EXPECT_NEAR(p.Sample(0.5).tip.x(), 0.05, 1e-15);
  EXPECT_NEAR(p.Sample(-1.0).tip.x(), 0.0, 1e-15);
  EXPECT_NEAR(p.Sample(9.0).tip.y(), 0.1, 1e-15);
  EXPECT_NEAR(p.Sample(1.5).blade_dir.norm(), 1.0, 1e-12);
}

TEST(ToolPathTest, MinimumJerkHasZeroSpeedAtKeyframesAndSameEnds) {
  const ToolPath p = ToolPath::Parse(kPath, "p.path");
  const double h = 1e-6;
  const auto x = [&](double t) { return p.Sample(t, PathTiming::kMinimumJerk).tip; };
  EXPECT_LT((x(1.0 + h) - x(1.0)).norm() / h, 1e-3);
  EXPECT_LT((x(1.0) - x(1.0 - h)).norm() / h, 1e-3);
  EXPECT_NEAR(x(0.5).x(), 0.05, 1e-12);  // symmetric profile: half way at half time
  // Peak speed of minimum-jerk is 1.875× the mean speed.
  const double v_mid = (x(0.5 + h) - x(0.5 - h)).norm() / (2 * h);
  EXPECT_NEAR(v_mid, 1.875 * 0.1, 1e-6);
}

TEST(ToolPathTest, ErrorsNameTheLine) {
  const auto err = [](const std::string& text) {
    try {
      ToolPath::Parse(text, "p.path");
    } catch (const InputError& e) {
      return std::string(e.what());
    }
    return std::string();
  };
  EXPECT_NE(err("0 0 0 0 0 0 1\n0 1 1 1 0 0 1\n").find("p.path:2"), std::string::npos);
  EXPECT_NE(err("0 0 0 0 0 0 1\n1 1 1 1 0 0\n").find("p.path:2"), std::string::npos);
  EXPECT_NE(err("0 0 0 0 0 0 0\n").find("p.path:1"), std::string::npos);
  EXPECT_NE(err("0 0 0 0 0 0 1 extra\n").find("p.path:1"), std::string::npos);
  EXPECT_NE(err("# nothing\n").find("no keyframes"), std::string::npos);
}

TEST(ToolPathTest, WriteReadRoundTrip) {
  const ToolPath p = ToolPath::Parse(kPath, "p.path");
  const auto file = std::filesystem::temp_directory_path() /
                    ("cutsim_tool_path_" + std::to_string(::getpid()) + ".path");
  p.Write(file);
  const ToolPath q = ToolPath::Read(file);
  std::filesystem::remove(file);
  ASSERT_EQ(q.keyframes().size(), p.keyframes().size());
  for (size_t i = 0; i < q.keyframes().size(); ++i) {
    EXPECT_NEAR((q.keyframes()[i].pose.tip - p.keyframes()[i].pose.tip).norm(), 0.0, 1e-9);
    EXPECT_NEAR((q.keyframes()[i].pose.blade_dir - p.keyframes()[i].pose.blade_dir).norm(), 0.0, 1e-8);
  }
}

}  // namespace
}  // namespace cutsim::haptics

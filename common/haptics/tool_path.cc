#include "common/haptics/tool_path.h"

#include <algorithm>
#include <cmath>
#include <fstream>
#include <sstream>

#include <fmt/format.h>

#include "common/core/error.h"
#include "common/core/input_file.h"

namespace cutsim::haptics {

ToolPath::ToolPath(std::vector<ToolKeyframe> keyframes, const std::string& source_name)
    : keyframes_(std::move(keyframes)) {
  for (size_t i = 0; i < keyframes_.size(); ++i) {
    auto& k = keyframes_[i];
    const std::string field = fmt::format("keyframe {}", i + 1);
    if (!std::isfinite(k.t) || !k.pose.tip.allFinite() || !k.pose.blade_dir.allFinite()) {
      ThrowInputError({.file = source_name, .field = field}, "values must be finite");
    }
    if (std::abs(k.t) > kMaxToolPathSeconds) {
      ThrowInputError({.file = source_name, .field = field},
                      fmt::format("time {:g} s is outside ±{:g} s", k.t, kMaxToolPathSeconds));
    }
    if (i > 0 && !(k.t > keyframes_[i - 1].t)) {
      ThrowInputError({.file = source_name, .field = field}, "times must increase strictly");
    }
    const double n = k.pose.blade_dir.norm();
    if (!(n > 1e-12)) {
      ThrowInputError({.file = source_name, .field = field}, "blade direction must be non-zero");
    }
    k.pose.blade_dir /= n;
  }
}

ToolPath ToolPath::Parse(const std::string& text, const std::string& source_name) {
  std::vector<ToolKeyframe> frames;
  std::istringstream in(text);
  std::string line;
  int64_t line_no = 0;
  while (std::getline(in, line)) {
    ++line_no;
    const auto hash = line.find('#');
    if (hash != std::string::npos) line.resize(hash);
    if (line.find_first_not_of(" \t\r") == std::string::npos) continue;
    std::istringstream fields(line);
    ToolKeyframe k;
    double v[7];
    int n = 0;
    while (n < 7 && fields >> v[n]) ++n;
    std::string extra;
    if (n != 7 || (fields >> extra)) {
      ThrowInputError({.file = source_name, .line = line_no},
                      "expected 7 numbers: t tip_x tip_y tip_z dir_x dir_y dir_z");
    }
    k.t = v[0];
    k.pose.tip = {v[1], v[2], v[3]};
    k.pose.blade_dir = {v[4], v[5], v[6]};
    if (!std::isfinite(k.t) || !k.pose.tip.allFinite() || !k.pose.blade_dir.allFinite()) {
      ThrowInputError({.file = source_name, .line = line_no}, "values must be finite");
    }
    if (std::abs(k.t) > kMaxToolPathSeconds) {
      ThrowInputError({.file = source_name, .line = line_no},
                      fmt::format("time {:g} s is outside ±{:g} s", k.t, kMaxToolPathSeconds));
    }
    if (!frames.empty() && !(k.t > frames.back().t)) {
      ThrowInputError({.file = source_name, .line = line_no}, "times must increase strictly");
    }
    if (!(k.pose.blade_dir.norm() > 1e-12)) {
      ThrowInputError({.file = source_name, .line = line_no}, "blade direction must be non-zero");
    }
    frames.push_back(k);
  }
  if (frames.empty()) ThrowFileError(source_name, "tool path has no keyframes");
  return ToolPath(std::move(frames), source_name);
}

ToolPath ToolPath::Read(const std::filesystem::path& path) {
  return Parse(ReadInputFile(path.string(), "tool path", kMaxToolPathBytes), path.string());
}

void ToolPath::Write(const std::filesystem::path& path) const {
  CheckOutputPath(path.string(), "tool path");  // the rename below would replace a device or a pipe
  const std::filesystem::path tmp = path.string() + ".tmp";
  {
    std::ofstream out(tmp);
    if (!out) ThrowFileError(tmp.string(), "cannot write tool path");
    out << "# cutsim tool path: t[s] tip_x tip_y tip_z [m] dir_x dir_y dir_z\n";
    for (const auto& k : keyframes_) {
      const ToolPose& p = k.pose;
      out << fmt::format("{:.9g} {:.9g} {:.9g} {:.9g} {:.9g} {:.9g} {:.9g}\n", k.t, p.tip.x(), p.tip.y(),
                         p.tip.z(), p.blade_dir.x(), p.blade_dir.y(), p.blade_dir.z());
    }
    if (!out) ThrowFileError(tmp.string(), "write failed");
  }
  std::filesystem::rename(tmp, path);
}

ToolPose ToolPath::Sample(double t, PathTiming timing) const {
  if (keyframes_.empty()) return {};
  if (t <= keyframes_.front().t) return keyframes_.front().pose;
  if (t >= keyframes_.back().t) return keyframes_.back().pose;
  const auto it = std::upper_bound(keyframes_.begin(), keyframes_.end(), t,
                                   [](double tt, const ToolKeyframe& k) { return tt < k.t; });
  const ToolKeyframe& b = *it;
  const ToolKeyframe& a = *(it - 1);
  double s = (t - a.t) / (b.t - a.t);
  if (timing == PathTiming::kMinimumJerk) {
    // s(τ) = 10τ³ − 15τ⁴ + 6τ⁵: zero velocity and acceleration at both ends.
    s = s * s * s * (10.0 + s * (-15.0 + 6.0 * s));
  }
  ToolPose out;
  out.tip = a.pose.tip + s * (b.pose.tip - a.pose.tip);
  Eigen::Vector3d d = a.pose.blade_dir + s * (b.pose.blade_dir - a.pose.blade_dir);
  const double n = d.norm();
  out.blade_dir = n > 1e-12 ? Eigen::Vector3d(d / n) : a.pose.blade_dir;
  return out;
}

}  // namespace cutsim::haptics

#include "haptic_client/virtual_devices.h"

#include <fmt/format.h>

#include "common/core/error.h"
#include "common/core/log.h"
#include "common/transport/codec.h"
#include "common/transport/lcm_log.h"
#include "cutsim/v1/wire.pb.h"

namespace cutsim::haptic_client {
namespace {

bool InWorkspace(const DeviceInfo& info, const Eigen::Vector3d& p) {
  return (p.array() >= info.workspace_min.array()).all() && (p.array() <= info.workspace_max.array()).all();
}

}  // namespace

ScriptedDevice::ScriptedDevice(haptics::ToolPath path, DeviceInfo info, haptics::PathTiming timing)
    : path_(std::move(path)), info_(std::move(info)), timing_(timing) {
  if (path_.empty()) ThrowInputError(SourceRef{.field = "--path"}, "the tool path has no keyframes");
  for (const auto& k : path_.keyframes()) {
    const Eigen::Vector3d& tip = k.pose.tip;
    if (!InWorkspace(info_, tip)) {
      Log().warn("tool path keyframe at t={} s ({}, {}, {}) m is outside the {} workspace", k.t, tip.x(), tip.y(),
                 tip.z(), info_.name);
    }
  }
}

void ScriptedDevice::Read(int64_t now_ns, DeviceState* state) noexcept {
  const double t = path_.start_time() + 1e-9 * static_cast<double>(now_ns - start_ns_);
  // Velocity of the scripted motion: central difference of the path (the
  // path has no derivative API; h = 0.1 ms is far below any segment).
  constexpr double kH = 1e-4;
  const double ta = std::max(path_.start_time(), t - kH);
  const double tb = std::min(path_.end_time(), t + kH);
  state->pose = path_.Sample(t, timing_);
  state->velocity = tb > ta ? Eigen::Vector3d((path_.Sample(tb, timing_).tip - path_.Sample(ta, timing_).tip) / (tb - ta))
                            : Eigen::Vector3d::Zero();
  state->buttons = 1;
  state->done = t >= path_.end_time();
}

ReplayDevice::ReplayDevice(const std::filesystem::path& log, const std::string& channel, DeviceInfo info)
    : info_(std::move(info)) {
  transport::LcmLogReader reader(log);
  v1::ToolState msg;
  int64_t first_us = 0;
  uint64_t last_seq = 0;
  size_t skipped = 0;
  size_t other_channels = 0;
  while (auto event = reader.Next()) {
    if (event->channel != channel) {
      ++other_channels;
      continue;
    }
    if (!transport::DecodeInto(event->data, msg, channel)) {
      ++skipped;
      continue;
    }
    ReplaySample s;
    s.pose.tip = {msg.tip().x(), msg.tip().y(), msg.tip().z()};
    s.pose.blade_dir = msg.has_blade_dir()
                           ? Eigen::Vector3d(msg.blade_dir().x(), msg.blade_dir().y(), msg.blade_dir().z())
                           : Eigen::Vector3d::UnitZ();
    s.velocity = {msg.velocity().x(), msg.velocity().y(), msg.velocity().z()};
    s.buttons = msg.buttons();
    const double n = s.pose.blade_dir.norm();
    if (!s.pose.tip.allFinite() || !s.velocity.allFinite() || !(n > 1e-9) || !std::isfinite(n) ||
        (!samples_.empty() && msg.seq() <= last_seq && msg.seq() != 0)) {
      ++skipped;
      continue;
    }
    s.pose.blade_dir /= n;
    if (samples_.empty()) first_us = event->timestamp_us;
    s.t = 1e-6 * static_cast<double>(event->timestamp_us - first_us);
    if (!samples_.empty() && s.t < samples_.back().t) {
      ++skipped;  // timestamps must not run backwards
      continue;
    }
    last_seq = msg.seq();
    samples_.push_back(s);
  }
  if (samples_.empty()) {
    ThrowFileError(log.string(), fmt::format("no usable {} events in the LCM log ({} on other channels, {} "
                                             "undecodable or invalid); check --session",
                                             channel, other_channels, skipped));
  }
  Log().info("replay: {} tool poses over {:.3f} s from {} ({} skipped)", samples_.size(), duration(),
             log.string(), skipped);
}

void ReplayDevice::Read(int64_t now_ns, DeviceState* state) noexcept {
  const double t = 1e-9 * static_cast<double>(now_ns - start_ns_);
  while (cursor_ + 1 < samples_.size() && samples_[cursor_ + 1].t <= t) ++cursor_;
  const ReplaySample& a = samples_[cursor_];
  if (cursor_ + 1 < samples_.size() && t > a.t) {
    const ReplaySample& b = samples_[cursor_ + 1];
    const double w = (t - a.t) / (b.t - a.t);
    state->pose.tip = (1.0 - w) * a.pose.tip + w * b.pose.tip;
  } else {
    state->pose.tip = a.pose.tip;
  }
  state->pose.blade_dir = a.pose.blade_dir;
  state->velocity = a.velocity;
  state->buttons = a.buttons;
  state->done = t >= samples_.back().t;
}

}  // namespace cutsim::haptic_client

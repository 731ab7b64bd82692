#include "haptic_client/device_guard.h"

#include <algorithm>
#include <cmath>

#include <fmt/format.h>

#include "common/core/error.h"

namespace cutsim::haptic_client {

DeviceGuard::DeviceGuard(HapticDevice& device, const GuardOptions& options)
    : device_(device), options_(options), info_(device.info()) {
  if (!(std::isfinite(options.scale) && options.scale > 0.0 && options.scale <= 1e3)) {
    ThrowInputError(SourceRef{.field = "workspace scale"}, fmt::format("{} is out of range (0, 1000]", options.scale));
  }
  if (!options.offset.allFinite()) ThrowInputError(SourceRef{.field = "workspace offset"}, "must be finite");
  if (!(std::isfinite(options.fade_s) && options.fade_s > 0.0 && options.fade_s <= 1.0)) {
    ThrowInputError(SourceRef{.field = "fade"}, fmt::format("{} s is out of range (0, 1] s", options.fade_s));
  }
  info_.workspace_min = options.scale * device.info().workspace_min + options.offset;
  info_.workspace_max = options.scale * device.info().workspace_max + options.offset;
}

void DeviceGuard::Start(int64_t start_ns) {
  now_ns_ = start_ns;
  device_.Start(start_ns);
}

void DeviceGuard::Read(int64_t now_ns, DeviceState* state) noexcept {
  const double dt = std::max(0.0, 1e-9 * static_cast<double>(now_ns - now_ns_));
  now_ns_ = now_ns;
  device_.Read(now_ns, &raw_);
  *state = raw_;
  const double step = dt / options_.fade_s;
  late_gain_ = raw_.late ? std::max(0.0, late_gain_ - step) : std::min(1.0, late_gain_ + step);
  if (raw_.lost || raw_.late) {
    if (raw_.lost && !stats_.lost) {
      stats_.lost = true;
      stats_.lost_ns = now_ns;
    }
    // The tool holds its last pose (before any, the reading's, mapped);
    // nothing moves and nothing cuts.
    if (!have_tool_) {
      tool_.tip = options_.scale * raw_.pose.tip + options_.offset;
      tool_.blade_dir = raw_.pose.blade_dir;
      have_tool_ = true;
    }
    state->pose = tool_;
    state->velocity.setZero();
    state->buttons = 0;
    return;
  }
  const bool clutch = options_.clutch_mask != 0 && (raw_.buttons & options_.clutch_mask) != 0;
  if (clutch && !have_tool_) {
    // Clutch held from the first reading: the tool starts at the mapped pose.
    tool_.tip = options_.scale * raw_.pose.tip + options_.offset;
    tool_.blade_dir = raw_.pose.blade_dir;
    have_tool_ = true;
  }
  if (clutch) {
    if (!clutched_) ++stats_.clutch_engagements;
    clutched_ = true;
    state->pose = tool_;
    state->velocity.setZero();
    state->buttons = raw_.buttons & ~options_.clutch_mask;
    return;
  }
  if (clutched_) {
    // Released: the offset takes up the device's move, the tool stays put.
    options_.offset = tool_.tip - options_.scale * raw_.pose.tip;
    clutched_ = false;
  }
  state->pose.tip = options_.scale * raw_.pose.tip + options_.offset;
  state->pose.blade_dir = raw_.pose.blade_dir;
  state->velocity = options_.scale * raw_.velocity;
  state->buttons = raw_.buttons & ~options_.clutch_mask;
  tool_ = state->pose;
  have_tool_ = true;
}

void DeviceGuard::SetForce(const Eigen::Vector3d& force) noexcept {
  const double max_force = info_.max_force;
  if (!(max_force > 0.0) || !force.allFinite()) {
    device_force_.setZero();
  } else {
    const double n = force.norm();
    device_force_ = force;
    if (n > max_force) {
      device_force_ *= max_force / n;
      ++stats_.force_clamped;
    }
    if (stats_.lost) {
      const double t = 1e-9 * static_cast<double>(now_ns_ - stats_.lost_ns);
      device_force_ *= std::max(0.0, 1.0 - t / options_.fade_s);
    }
    device_force_ *= late_gain_;
  }
  device_.SetForce(device_force_);
}

}  // namespace cutsim::haptic_client

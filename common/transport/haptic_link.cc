#include "common/transport/haptic_link.h"

#include <poll.h>
#include <pthread.h>

#include <algorithm>
#include <cmath>
#include <cstring>
#include <exception>
#include <limits>

#include "common/core/clock.h"
#include "common/core/log.h"
#include "common/transport/channels.h"
#include "common/transport/proto_vec.h"
#include "common/transport/realtime_thread.h"

namespace cutsim::transport {
namespace {

constexpr double kMaxToolPosition = 100.0;  // m: no tool is 100 m from the origin
constexpr double kMaxToolSpeed = 100.0;     // m/s: no hand moves a tool that fast

std::unique_ptr<FaultInjector> MakeReceiveFaults(const FaultConfig& config) {
  ValidateFaultConfig(config);
  if (!config.active()) return nullptr;
  return std::make_unique<FaultInjector>(config);
}

/// Milliseconds from `now_ns` until `due_ns` (rounded up), capped at `cap_ms`.
int WaitMs(int64_t now_ns, int64_t due_ns, int cap_ms) {
  if (due_ns == std::numeric_limits<int64_t>::max()) return cap_ms;
  const int64_t until_due_ms = std::max<int64_t>(0, (due_ns - now_ns + 999'999) / 1'000'000);
  return static_cast<int>(std::min<int64_t>(cap_ms, until_due_ms));
}

/// Waits up to `timeout_ms` for LCM's descriptor or the wake-up eventfd.
/// Returns whether LCM has something to dispatch (EINTR counts as "maybe").
bool WaitLcmOrWake(int lcm_fd, const WakeFd& wake, int timeout_ms) {
  pollfd fds[2] = {{.fd = lcm_fd, .events = POLLIN, .revents = 0},
                   {.fd = wake.fd(), .events = POLLIN, .revents = 0}};
  const int n = ::poll(fds, 2, timeout_ms);
  if (n < 0) return true;
  return (fds[0].revents & (POLLIN | POLLERR | POLLHUP)) != 0;
}

/// A tool pose the server may use: finite, within any workspace, a usable blade.
bool ValidTool(ToolSample* s) {
  ToolPose& pose = s->pose;
  if (!pose.tip.allFinite() || !s->velocity.allFinite() || !pose.blade_dir.allFinite()) return false;
  if (pose.tip.norm() > kMaxToolPosition || s->velocity.norm() > kMaxToolSpeed) return false;
  const double n = pose.blade_dir.norm();
  if (!(n > 1e-9)) return false;
  pose.blade_dir /= n;
  return true;
}

}  // namespace

// ---- Conversions ---------------------------------------------------------------

void ToProto(const haptics::LocalModel& m, v1::HapticModel* msg) {
  msg->set_seq(m.seq);
  msg->set_stamp_ns(m.stamp_ns);
  msg->set_sim_time(m.sim_time);
  msg->set_contact(m.contact);
  SetVec3(m.x0, msg->mutable_x0());
  SetVec3(m.normal, msg->mutable_normal());
  SetVec3(m.f0, msg->mutable_f0());
  auto* k = msg->mutable_stiffness()->mutable_m();
  k->Resize(9, 0.0);
  for (int r = 0; r < 3; ++r) {
    for (int c = 0; c < 3; ++c) k->Set(3 * r + c, m.stiffness(r, c));
  }
  msg->set_damping(m.damping);
  msg->set_valid_for(m.valid_for);
  msg->mutable_cut()->set_cuts(m.cut.cuts);
  msg->mutable_cut()->set_cutting(m.cut.cutting);
  msg->mutable_cut()->set_decay_per_second(m.cut.decay_per_second);
  msg->set_topology_version(m.topology_version);
}

bool FromProto(const v1::HapticModel& msg, haptics::LocalModel* m) noexcept {
  m->seq = msg.seq();
  m->stamp_ns = msg.stamp_ns();
  m->sim_time = msg.sim_time();
  m->contact = msg.contact();
  m->x0 = FromVec3(msg.x0());
  m->normal = FromVec3(msg.normal());
  m->f0 = FromVec3(msg.f0());
  const int n = msg.stiffness().m_size();
  if (n == 9) {
    for (int r = 0; r < 3; ++r) {
      for (int c = 0; c < 3; ++c) m->stiffness(r, c) = msg.stiffness().m(3 * r + c);
    }
  } else if (n == 0) {
    m->stiffness.setZero();
  } else {
    return false;
  }
  m->damping = msg.damping();
  m->valid_for = msg.valid_for();
  m->cut.cuts = msg.cut().cuts();
  m->cut.cutting = msg.cut().cutting();
  m->cut.decay_per_second = msg.cut().decay_per_second();
  m->topology_version = msg.topology_version();
  return true;
}

void ToProto(const ToolSample& s, v1::ToolState* msg) {
  msg->set_seq(s.seq);
  msg->set_stamp_ns(s.stamp_ns);
  SetVec3(s.pose.tip, msg->mutable_tip());
  SetVec3(s.pose.blade_dir, msg->mutable_blade_dir());
  SetVec3(s.velocity, msg->mutable_velocity());
  msg->set_buttons(s.buttons);
}

ToolSample FromProto(const v1::ToolState& msg) noexcept {
  ToolSample s;
  s.seq = msg.seq();
  s.stamp_ns = msg.stamp_ns();
  s.pose.tip = FromVec3(msg.tip());
  s.pose.blade_dir = msg.has_blade_dir() ? FromVec3(msg.blade_dir()) : Eigen::Vector3d::UnitZ();
  s.velocity = FromVec3(msg.velocity());
  s.buttons = msg.buttons();
  return s;
}

// ---- StreamSequencer -------------------------------------------------------------

StreamSequencer::Verdict StreamSequencer::Offer(uint64_t seq, int64_t stamp_ns) noexcept {
  Verdict verdict = Verdict::kAccepted;
  if (have_) {
    if (seq == seq_) return Verdict::kDuplicate;
    if (seq < seq_) {
      // Lower seq: a restarted sender stamps it later than what we hold (same
      // clock); a reordered or replayed message stamps it earlier.
      if (stamp_ns > stamp_ns_ || seq_ - seq > restart_window_) {
        verdict = Verdict::kRestart;
      } else {
        return Verdict::kStale;
      }
    }
  }
  have_ = true;
  seq_ = seq;
  stamp_ns_ = stamp_ns;
  return verdict;
}

// ---- HapticServerLink --------------------------------------------------------------

HapticServerLink::HapticServerLink(LcmBus& bus, std::string session, HapticLinkOptions options)
    : bus_(bus),
      session_(std::move(session)),
      options_(options),
      model_channel_(LcmChannelName(session_, LcmChannel::kModel)),
      sequencer_(options.restart_window) {
  ValidateFaultConfig(options_.publish_faults);
  receive_faults_ = MakeReceiveFaults(options_.receive_faults);
  publisher_ = std::make_unique<FaultyLcmPublisher>(bus_, model_channel_, options_.publish_faults);
  model_msg_.set_session(session_);
  subscription_ = bus_.Subscribe<v1::ToolState>(LcmChannelName(session_, LcmChannel::kTool),
                                                [this](const v1::ToolState& msg) { OnTool(msg); });
}

HapticServerLink::~HapticServerLink() { StopReceiving(); }

void HapticServerLink::StartReceiving(int rt_priority) {
  if (receive_running_.exchange(true)) return;
  receive_thread_ = std::thread([this, rt_priority] {
    pthread_setname_np(pthread_self(), "cutsim-lcm-rx");
    (void)RaiseCurrentThread(rt_priority, "server's LCM receive thread", "poses and models");
    constexpr int kIdleWaitMs = 100;  // only bounds how long Stop waits
    try {
      const int lcm_fd = bus_.fileno();
      while (receive_running_.load(std::memory_order_relaxed)) {
        int64_t due = std::numeric_limits<int64_t>::max();
        if (receive_faults_ != nullptr) due = receive_faults_->next_due_ns();
        const bool lcm_ready = WaitLcmOrWake(lcm_fd, wake_, WaitMs(MonotonicNs(), due, kIdleWaitMs));
        wake_.Drain();
        if (lcm_ready || receive_faults_ != nullptr) ReceivePending();
      }
    } catch (const std::exception& e) {
      Log().error("haptic link receive thread stopped: {}", e.what());
    }
  });
}

void HapticServerLink::StopReceiving() {
  receive_running_.store(false);
  wake_.Notify();
  if (receive_thread_.joinable()) receive_thread_.join();
}

void HapticServerLink::ReceivePending() {
  bus_.HandleTimeout(0);
  const int64_t now = MonotonicNs();
  if (receive_faults_ != nullptr) {
    receive_faults_->Release(now, [&](std::span<const uint8_t> bytes) {
      if (DecodeInto(bytes, scratch_, subscription_.channel())) ProcessTool(scratch_, now);
    });
  }
  const auto& sub = subscription_.stats();
  stats_.received.store(sub.received, std::memory_order_relaxed);
  stats_.superseded.store(sub.superseded, std::memory_order_relaxed);
  stats_.decode_errors.store(sub.decode_errors, std::memory_order_relaxed);
}

void HapticServerLink::OnTool(const v1::ToolState& msg) {
  const int64_t now = MonotonicNs();
  if (receive_faults_ == nullptr) {
    ProcessTool(msg, now);
    return;
  }
  // Re-encode (the bus hands us decoded messages) and let the injector decide.
  if (const auto bytes = encoder_.Encode(msg)) receive_faults_->Submit(*bytes, now);
}

void HapticServerLink::ProcessTool(const v1::ToolState& msg, int64_t receive_ns) {
  auto bump = [](std::atomic<uint64_t>& counter) { counter.fetch_add(1, std::memory_order_relaxed); };
  if (msg.session() != session_) {
    bump(stats_.foreign_session);
    return;
  }
  if (options_.authenticator != nullptr) {
    switch (options_.authenticator->Verify(msg)) {
      case AuthVerdict::kOk:
        break;
      case AuthVerdict::kNewEpoch:
        // The sender restarted (authenticated): its new stream starts afresh.
        if (sequencer_.has_value()) bump(stats_.restarts);
        sequencer_.Reset();
        break;
      case AuthVerdict::kUnsigned:
        bump(stats_.unauthenticated);
        bump(stats_.auth_unsigned);
        return;
      case AuthVerdict::kForged:
        bump(stats_.unauthenticated);
        bump(stats_.auth_forged);
        return;
      case AuthVerdict::kOutsideWindow:
      case AuthVerdict::kInvalidEpoch:
        bump(stats_.auth_outside_window);
        [[fallthrough]];
      case AuthVerdict::kReplayed:
      case AuthVerdict::kOtherSender:
        bump(stats_.unauthenticated);
        bump(stats_.auth_replayed);
        return;
    }
  }
  ToolSample sample = FromProto(msg);
  if (!ValidTool(&sample)) {
    bump(stats_.invalid);
    return;
  }
  switch (sequencer_.Offer(sample.seq, sample.stamp_ns)) {
    case StreamSequencer::Verdict::kDuplicate:
      bump(stats_.duplicate);
      return;
    case StreamSequencer::Verdict::kStale:
      bump(stats_.stale);
      return;
    case StreamSequencer::Verdict::kRestart:
      bump(stats_.restarts);
      break;
    case StreamSequencer::Verdict::kAccepted:
      break;
  }
  sample.receive_ns = receive_ns;
  tool_box_.Write(sample);
  bump(stats_.accepted);
}

std::optional<ToolSample> HapticServerLink::PollTool() {
  if (!receiving()) ReceivePending();
  publisher_->Poll(MonotonicNs());
  if (!tool_box_.TakeFresh()) return std::nullopt;
  latest_ = tool_box_.front();
  return latest_;
}

void HapticServerLink::PublishModel(const haptics::LocalModel& model, uint64_t tool_seq) {
  const int64_t now = MonotonicNs();
  try {
    ToProto(model, &model_msg_);
  } catch (...) {
    stats_.models_not_sent.fetch_add(1, std::memory_order_relaxed);  // allocation failure, first message only
    return;
  }
  model_msg_.set_seq(++model_seq_);
  model_msg_.set_stamp_ns(now);
  model_msg_.set_tool_seq(tool_seq);
  if (publisher_->Publish(model_msg_, now) == PublishStatus::kOk) {
    stats_.models_published.fetch_add(1, std::memory_order_relaxed);
  } else {
    stats_.models_not_sent.fetch_add(1, std::memory_order_relaxed);
  }
  publisher_->Poll(now);
}

HapticServerLinkStats HapticServerLink::stats() const {
  HapticServerLinkStats s;
  s.received = stats_.received.load();
  s.superseded = stats_.superseded.load();
  s.decode_errors = stats_.decode_errors.load();
  s.accepted = stats_.accepted.load();
  s.foreign_session = stats_.foreign_session.load();
  s.stale = stats_.stale.load();
  s.duplicate = stats_.duplicate.load();
  s.invalid = stats_.invalid.load();
  s.unauthenticated = stats_.unauthenticated.load();
  s.auth_unsigned = stats_.auth_unsigned.load();
  s.auth_forged = stats_.auth_forged.load();
  s.auth_replayed = stats_.auth_replayed.load();
  s.auth_outside_window = stats_.auth_outside_window.load();
  s.restarts = stats_.restarts.load();
  s.models_published = stats_.models_published.load();
  s.models_not_sent = stats_.models_not_sent.load();
  return s;
}

// ---- HapticClientLink ----------------------------------------------------------------

HapticClientLink::HapticClientLink(LcmBus& bus, std::string session, HapticLinkOptions options)
    : bus_(bus),
      session_(std::move(session)),
      options_(options),
      tool_channel_(LcmChannelName(session_, LcmChannel::kTool)),
      sequencer_(options.restart_window) {
  ValidateFaultConfig(options_.publish_faults);
  receive_faults_ = MakeReceiveFaults(options_.receive_faults);
  publisher_ = std::make_unique<FaultyLcmPublisher>(bus_, tool_channel_, options_.publish_faults);
  tool_msg_.set_session(session_);
  subscription_ = bus_.Subscribe<v1::HapticModel>(LcmChannelName(session_, LcmChannel::kModel),
                                                  [this](const v1::HapticModel& msg) { OnModel(msg); });
}

HapticClientLink::~HapticClientLink() { Stop(); }

void HapticClientLink::Start(int wait_ms, int rt_priority) {
  if (running_.exchange(true)) return;
  thread_ = std::thread([this, wait_ms, rt_priority] {
    pthread_setname_np(pthread_self(), "cutsim-lcm");
    (void)RaiseCurrentThread(rt_priority, "haptic client's LCM thread", "poses and models");
    try {
      while (running_.load(std::memory_order_relaxed)) RunOnce(wait_ms);
    } catch (const std::exception& e) {
      Log().error("haptic link LCM thread stopped: {}", e.what());
    }
  });
}

void HapticClientLink::Stop() {
  running_.store(false);
  wake_.Notify();
  if (thread_.joinable()) thread_.join();
}

int HapticClientLink::RunOnce(int wait_ms) {
  const uint64_t before = stats_.accepted.load(std::memory_order_relaxed);
  int64_t now = MonotonicNs();
  // Drain the wake-up before taking the mailbox: a sample published after
  // this point notifies again, so the wait below cannot sleep on it.
  wake_.Drain();
  SendPendingTool(now);
  // Wake in time for the next fault-delayed message.
  int64_t due = publisher_->injector().next_due_ns();
  if (receive_faults_ != nullptr) due = std::min(due, receive_faults_->next_due_ns());
  const bool lcm_ready = WaitLcmOrWake(bus_.fileno(), wake_, WaitMs(now, due, std::max(0, wait_ms)));
  if (lcm_ready) bus_.HandleTimeout(0);
  now = MonotonicNs();
  if (receive_faults_ != nullptr) {
    receive_faults_->Release(now, [&](std::span<const uint8_t> bytes) {
      if (DecodeInto(bytes, scratch_, subscription_.channel())) ProcessModel(scratch_, now);
    });
  }
  wake_.Drain();
  SendPendingTool(now);
  const auto& sub = subscription_.stats();
  stats_.models_received.store(sub.received, std::memory_order_relaxed);
  stats_.models_superseded.store(sub.superseded, std::memory_order_relaxed);
  stats_.decode_errors.store(sub.decode_errors, std::memory_order_relaxed);
  return static_cast<int>(stats_.accepted.load(std::memory_order_relaxed) - before);
}

void HapticClientLink::SendPendingTool(int64_t now_ns) {
  if (tool_box_.TakeFresh()) {
    const ToolSample& s = tool_box_.front();
    ToProto(s, &tool_msg_);
    if (options_.authenticator != nullptr) options_.authenticator->Sign(&tool_msg_);
    if (publisher_->Publish(tool_msg_, now_ns) == PublishStatus::kOk) {
      stats_.tools_published.fetch_add(1, std::memory_order_relaxed);
    } else {
      stats_.tools_not_sent.fetch_add(1, std::memory_order_relaxed);
    }
  }
  publisher_->Poll(now_ns);
}

void HapticClientLink::OnModel(const v1::HapticModel& msg) {
  const int64_t now = MonotonicNs();
  if (receive_faults_ == nullptr) {
    ProcessModel(msg, now);
    return;
  }
  if (const auto bytes = encoder_.Encode(msg)) receive_faults_->Submit(*bytes, now);
}

void HapticClientLink::ProcessModel(const v1::HapticModel& msg, int64_t receive_ns) {
  if (msg.session() != session_) {
    stats_.foreign_session.fetch_add(1, std::memory_order_relaxed);
    return;
  }
  if (!FromProto(msg, &staging_.model)) {
    stats_.malformed.fetch_add(1, std::memory_order_relaxed);
    return;
  }
  switch (sequencer_.Offer(msg.seq(), msg.stamp_ns())) {
    case StreamSequencer::Verdict::kDuplicate:
      stats_.duplicate.fetch_add(1, std::memory_order_relaxed);
      return;
    case StreamSequencer::Verdict::kStale:
      stats_.stale.fetch_add(1, std::memory_order_relaxed);
      return;
    case StreamSequencer::Verdict::kRestart:
      ++epoch_;
      stats_.restarts.fetch_add(1, std::memory_order_relaxed);
      break;
    case StreamSequencer::Verdict::kAccepted:
      break;
  }
  staging_.receive_ns = receive_ns;
  staging_.tool_seq = msg.tool_seq();
  staging_.epoch = epoch_;
  model_box_.Write(staging_);
  stats_.accepted.fetch_add(1, std::memory_order_relaxed);
}

uint64_t HapticClientLink::PublishTool(const ToolSample& sample) noexcept {
  ToolSample& slot = tool_box_.back();
  slot = sample;
  slot.seq = ++next_tool_seq_;
  if (slot.stamp_ns == 0) slot.stamp_ns = MonotonicNs();
  slot.receive_ns = 0;
  const uint64_t seq = slot.seq;
  tool_box_.Publish();
  stats_.tools_written.fetch_add(1, std::memory_order_relaxed);
  wake_.Notify();  // the LCM thread sends it now, not at its next timeout
  return seq;
}

bool HapticClientLink::TakeModel(ReceivedModel* out) noexcept { return model_box_.Read(out); }

HapticClientLinkStats HapticClientLink::stats() const {
  HapticClientLinkStats s;
  s.tools_written = stats_.tools_written.load();
  s.tools_published = stats_.tools_published.load();
  s.tools_not_sent = stats_.tools_not_sent.load();
  const uint64_t handled = s.tools_published + s.tools_not_sent;
  s.tools_coalesced = s.tools_written > handled ? s.tools_written - handled : 0;
  s.models_received = stats_.models_received.load();
  s.models_superseded = stats_.models_superseded.load();
  s.decode_errors = stats_.decode_errors.load();
  s.foreign_session = stats_.foreign_session.load();
  s.stale = stats_.stale.load();
  s.duplicate = stats_.duplicate.load();
  s.malformed = stats_.malformed.load();
  s.restarts = stats_.restarts.load();
  s.accepted = stats_.accepted.load();
  return s;
}

FaultStats HapticClientLink::publish_fault_stats() const { return publisher_->injector().stats(); }

FaultStats HapticClientLink::receive_fault_stats() const {
  return receive_faults_ != nullptr ? receive_faults_->stats() : FaultStats{};
}

}  // namespace cutsim::transport

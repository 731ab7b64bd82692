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
#include "common/transport/haptic_link_util.h"
#include "common/transport/realtime_thread.h"

namespace cutsim::transport {
namespace {

using link_detail::MakeReceiveFaults;
using link_detail::SnapshotPackets;
using link_detail::WaitInputOrWake;
using link_detail::WaitMs;

constexpr double kMaxToolPosition = 100.0;  // m: no tool is 100 m from the origin
constexpr double kMaxToolSpeed = 100.0;     // m/s: no hand moves a tool that fast

}  // namespace

PacketCounts link_detail::SnapshotPackets(const PacketCounters& counters, uint64_t queued, const UdpmReceiver* receiver) {
  PacketCounts c;
  for (size_t i = 0; i < kPacketReasonCount; ++i) c.n[i] = counters.get(static_cast<PacketReason>(i));
  // Queued but never taken: a newer one replaced it (or it still waits).
  const uint64_t taken = c[PacketReason::kAccepted];
  c.n[static_cast<size_t>(PacketReason::kSuperseded)] = queued > taken ? queued - taken : 0;
  c.packet_level = receiver != nullptr;
  c.kernel_dropped = receiver != nullptr ? receiver->kernel_dropped() : 0;
  return c;
}

namespace {

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
      tool_channel_(LcmChannelName(session_, LcmChannel::kTool)),
      model_channel_(LcmChannelName(session_, LcmChannel::kModel)),
      sequencer_(options.restart_window),
      model_epoch_(static_cast<uint64_t>(RealtimeNowNs())) {
  ValidateFaultConfig(options_.publish_faults);
  receive_faults_ = MakeReceiveFaults(options_.receive_faults);
  publisher_ = std::make_unique<FaultyLcmPublisher>(bus_, model_channel_, options_.publish_faults);
  model_msg_.set_session(session_);
  if (ParseUdpmAddress(bus_.url())) {
    receiver_ = std::make_unique<UdpmReceiver>(bus_.url(), tool_channel_, packets_,
                                               UdpmReceiver::Options{.max_payload = MaxPayloadBytes<v1::ToolState>()});
  } else {
    subscription_ = bus_.SubscribeRaw(tool_channel_, MaxPayloadBytes<v1::ToolState>(),
                                      [this](std::span<const uint8_t> bytes) { OnToolBytes(bytes, MonotonicNs()); });
  }
}

HapticServerLink::~HapticServerLink() { StopReceiving(); }

void HapticServerLink::StartReceiving(int rt_priority) {
  if (receive_running_.exchange(true)) return;
  receive_thread_ = std::thread([this, rt_priority] {
    pthread_setname_np(pthread_self(), "cutsim-lcm-rx");
    (void)RaiseCurrentThread(rt_priority, "server's LCM receive thread", "poses and models");
    constexpr int kIdleWaitMs = 100;  // only bounds how long Stop waits
    try {
      while (receive_running_.load(std::memory_order_relaxed)) {
        int64_t due = std::numeric_limits<int64_t>::max();
        if (receive_faults_ != nullptr) due = receive_faults_->next_due_ns();
        const bool lcm_ready = WaitForInput(WaitMs(MonotonicNs(), due, kIdleWaitMs));
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

bool HapticServerLink::WaitForInput(int timeout_ms) {
  return WaitInputOrWake(receiver_ != nullptr ? receiver_->fd() : bus_.fileno(), wake_, timeout_ms);
}

void HapticServerLink::ReceivePending() {
  if (receiver_ != nullptr) {
    receiver_->Drain([this](std::span<const uint8_t> bytes, int64_t receive_ns) {
      stats_.received.fetch_add(1, std::memory_order_relaxed);
      OnToolBytes(bytes, receive_ns);
    });
  } else {
    bus_.HandleTimeout(0);
  }
  const int64_t now = MonotonicNs();
  if (receive_faults_ != nullptr) {
    receive_faults_->Release(now, [&](std::span<const uint8_t> bytes) { ProcessToolBytes(bytes, now); });
  }
  if (receiver_ == nullptr) {
    const auto& sub = subscription_.stats();
    stats_.received.store(sub.received, std::memory_order_relaxed);
    stats_.superseded.store(sub.superseded, std::memory_order_relaxed);
    stats_.subscription_errors.store(sub.decode_errors, std::memory_order_relaxed);
  }
}

void HapticServerLink::OnToolBytes(std::span<const uint8_t> bytes, int64_t receive_ns) {
  if (receive_faults_ == nullptr) {
    ProcessToolBytes(bytes, receive_ns);
  } else {
    receive_faults_->Submit(bytes, receive_ns);  // the injector decides its fate
  }
}

void HapticServerLink::ProcessToolBytes(std::span<const uint8_t> bytes, int64_t receive_ns) {
  if (!DecodeInto(bytes, scratch_, tool_channel_)) {
    stats_.decode_errors.fetch_add(1, std::memory_order_relaxed);
    packets_.Add(PacketReason::kDecodeError);
    return;
  }
  ProcessTool(scratch_, receive_ns);
}

void HapticServerLink::ProcessTool(const v1::ToolState& msg, int64_t receive_ns) {
  auto bump = [](std::atomic<uint64_t>& counter) { counter.fetch_add(1, std::memory_order_relaxed); };
  if (msg.session() != session_) {
    bump(stats_.foreign_session);
    packets_.Add(PacketReason::kForeignSession);
    return;
  }
  if (options_.authenticator != nullptr) {
    const AuthVerdict verdict = options_.authenticator->Verify(msg);
    switch (verdict) {
      case AuthVerdict::kOk:
        break;
      case AuthVerdict::kNewEpoch:
        // The sender restarted (authenticated): its new stream starts afresh.
        if (sequencer_.has_value()) bump(stats_.restarts);
        sequencer_.Reset();
        break;
      case AuthVerdict::kUnsigned:
        bump(stats_.auth_unsigned);
        break;
      case AuthVerdict::kForged:
        bump(stats_.auth_forged);
        break;
      case AuthVerdict::kOutsideWindow:
      case AuthVerdict::kInvalidEpoch:
        bump(stats_.auth_outside_window);
        [[fallthrough]];
      case AuthVerdict::kReplayed:
      case AuthVerdict::kOtherSender:
        bump(stats_.auth_replayed);
        break;
    }
    if (!Accepted(verdict)) {
      bump(stats_.unauthenticated);
      packets_.Add(ReasonOf(verdict));
      return;
    }
  }
  ToolSample sample = FromProto(msg);
  if (!ValidTool(&sample)) {
    bump(stats_.invalid);
    packets_.Add(PacketReason::kInvalid);
    return;
  }
  switch (sequencer_.Offer(sample.seq, sample.stamp_ns)) {
    case StreamSequencer::Verdict::kDuplicate:
      bump(stats_.duplicate);
      packets_.Add(PacketReason::kStale);
      return;
    case StreamSequencer::Verdict::kStale:
      bump(stats_.stale);
      packets_.Add(PacketReason::kStale);
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
  packets_.Add(PacketReason::kAccepted);
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
  if (options_.model_auth != nullptr) {
    model_msg_.set_epoch(model_epoch_);
    model_msg_.set_wall_ns(RealtimeNowNs());
  }
  // Serialised into a fixed buffer (no allocation), the trailer appended.
  const size_t size = model_msg_.ByteSizeLong();
  const size_t trailer = options_.model_auth != nullptr ? kTrailerBytes : 0;
  if (size + trailer > kLcmMaxPayloadBytes) {
    stats_.models_not_sent.fetch_add(1, std::memory_order_relaxed);
    return;
  }
  model_msg_.SerializeWithCachedSizesToArray(model_bytes_.data());
  const std::span<const uint8_t> body(model_bytes_.data(), size);
  if (trailer > 0 &&
      !options_.model_auth->MakeTrailer(body, std::span<uint8_t, kTrailerBytes>(model_bytes_.data() + size,
                                                                                kTrailerBytes))) {
    stats_.models_not_sent.fetch_add(1, std::memory_order_relaxed);
    return;
  }
  if (publisher_->PublishBytes(std::span<const uint8_t>(model_bytes_.data(), size + trailer), now) ==
      PublishStatus::kOk) {
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
  s.decode_errors = stats_.decode_errors.load() + stats_.subscription_errors.load();
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
  s.packets = SnapshotPackets(packets_, s.accepted, receiver_.get());
  if (receiver_ != nullptr) s.superseded = s.packets[PacketReason::kSuperseded];
  return s;
}

}  // namespace cutsim::transport

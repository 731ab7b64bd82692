// The haptic station's end of the link (haptic_link.h): tool poses out,
// models in, checked on the LCM thread before the servo loop sees them.
#include <pthread.h>

#include <algorithm>
#include <exception>
#include <limits>

#include "common/core/clock.h"
#include "common/core/log.h"
#include "common/transport/channels.h"
#include "common/transport/haptic_link.h"
#include "common/transport/haptic_link_util.h"
#include "common/transport/realtime_thread.h"

namespace cutsim::transport {
namespace {

using link_detail::MakeReceiveFaults;
using link_detail::SnapshotPackets;
using link_detail::WaitInputOrWake;
using link_detail::WaitMs;

constexpr int64_t kLinkWarnPeriodNs = 1'000'000'000;

}  // namespace

HapticClientLink::HapticClientLink(LcmBus& bus, std::string session, HapticLinkOptions options)
    : bus_(bus),
      session_(std::move(session)),
      options_(options),
      tool_channel_(LcmChannelName(session_, LcmChannel::kTool)),
      model_channel_(LcmChannelName(session_, LcmChannel::kModel)),
      sequencer_(options.restart_window),
      gate_(options.model_window_ns),
      last_accept_ns_(MonotonicNs()) {
  ValidateFaultConfig(options_.publish_faults);
  receive_faults_ = MakeReceiveFaults(options_.receive_faults);
  publisher_ = std::make_unique<FaultyLcmPublisher>(bus_, tool_channel_, options_.publish_faults);
  tool_msg_.set_session(session_);
  // The largest model accepted: one datagram with the trailer.
  const size_t max_bytes = MaxPayloadBytes<v1::HapticModel>();
  if (ParseUdpmAddress(bus_.url())) {
    receiver_ = std::make_unique<UdpmReceiver>(bus_.url(), model_channel_, packets_,
                                               UdpmReceiver::Options{.max_payload = max_bytes});
  } else {
    subscription_ = bus_.SubscribeRaw(model_channel_, max_bytes, [this](std::span<const uint8_t> bytes) {
      OnModelBytes(bytes, MonotonicNs());
    });
  }
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
  const int input_fd = receiver_ != nullptr ? receiver_->fd() : bus_.fileno();
  // Counted before blocking: a caller that sees the count knows the thread
  // has reached (or is entering) this wait with nothing left to send.
  stats_.waits.fetch_add(1, std::memory_order_release);
  const bool ready = WaitInputOrWake(input_fd, wake_, WaitMs(now, due, std::max(0, wait_ms)));
  if (ready) {
    if (receiver_ != nullptr) {
      receiver_->Drain([this](std::span<const uint8_t> bytes, int64_t receive_ns) {
        stats_.models_received.fetch_add(1, std::memory_order_relaxed);
        OnModelBytes(bytes, receive_ns);
      });
    } else {
      bus_.HandleTimeout(0);
    }
  }
  now = MonotonicNs();
  if (receive_faults_ != nullptr) {
    receive_faults_->Release(now, [&](std::span<const uint8_t> bytes) { ProcessModelBytes(bytes, now); });
  }
  wake_.Drain();
  SendPendingTool(now);
  if (receiver_ == nullptr) {
    const auto& sub = subscription_.stats();
    stats_.models_received.store(sub.received, std::memory_order_relaxed);
    stats_.models_superseded.store(sub.superseded, std::memory_order_relaxed);
    stats_.subscription_errors.store(sub.decode_errors, std::memory_order_relaxed);
  }
  ExplainSilence(now);
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

void HapticClientLink::OnModelBytes(std::span<const uint8_t> bytes, int64_t receive_ns) {
  if (receive_faults_ == nullptr) {
    ProcessModelBytes(bytes, receive_ns);
  } else {
    receive_faults_->Submit(bytes, receive_ns);  // the injector decides its fate
  }
}

void HapticClientLink::Refuse(PacketReason reason) {
  packets_.Add(reason);
  ++refused_since_warn_[static_cast<size_t>(reason)];
}

bool HapticClientLink::Authenticate(std::span<const uint8_t> bytes, std::span<const uint8_t>* body) {
  *body = bytes;
  if (options_.model_auth == nullptr) return true;
  // The tag first, on the raw bytes: a forged model is never parsed.
  const AuthVerdict verdict = options_.model_auth->Check(bytes, body);
  if (verdict == AuthVerdict::kOk) return true;
  Refuse(ReasonOf(verdict));
  return false;
}

void HapticClientLink::ProcessModelBytes(std::span<const uint8_t> bytes, int64_t receive_ns) {
  std::span<const uint8_t> body;
  if (!Authenticate(bytes, &body)) return;
  if (!DecodeInto(body, scratch_, model_channel_)) {
    stats_.decode_errors.fetch_add(1, std::memory_order_relaxed);
    Refuse(PacketReason::kDecodeError);
    return;
  }
  ProcessModel(scratch_, receive_ns);
}

void HapticClientLink::ProcessModel(const v1::HapticModel& msg, int64_t receive_ns) {
  if (msg.session() != session_) {
    stats_.foreign_session.fetch_add(1, std::memory_order_relaxed);
    Refuse(PacketReason::kForeignSession);
    return;
  }
  bool new_server = false;
  if (options_.model_auth != nullptr) {
    const uint64_t followed = gate_.epoch();
    const AuthVerdict verdict = gate_.Offer(msg.epoch(), msg.seq(), msg.wall_ns(), RealtimeNowNs(), receive_ns);
    if (!Accepted(verdict)) {
      Refuse(ReasonOf(verdict));
      if (verdict == AuthVerdict::kOtherSender && receive_ns - last_two_servers_warn_ns_ >= kLinkWarnPeriodNs) {
        last_two_servers_warn_ns_ = receive_ns;
        Log().warn("two servers publish session '{}': models from a server started at epoch {} are refused "
                   "while the one started at epoch {} is alive",
                   session_, msg.epoch(), followed);
      }
      return;
    }
    if (verdict == AuthVerdict::kNewEpoch && followed != 0) {
      new_server = true;
      Log().info("session '{}': a restarted server (epoch {}) publishes models; following it", session_,
                 msg.epoch());
    }
  }
  if (!FromProto(msg, &staging_.model)) {
    stats_.malformed.fetch_add(1, std::memory_order_relaxed);
    Refuse(PacketReason::kInvalid);
    return;
  }
  if (new_server) sequencer_.Reset();
  const uint64_t previous = sequencer_.seq();  // 0: none held
  switch (sequencer_.Offer(msg.seq(), msg.stamp_ns())) {
    case StreamSequencer::Verdict::kDuplicate:
      stats_.duplicate.fetch_add(1, std::memory_order_relaxed);
      Refuse(PacketReason::kStale);
      return;
    case StreamSequencer::Verdict::kStale:
      stats_.stale.fetch_add(1, std::memory_order_relaxed);
      Refuse(PacketReason::kStale);
      return;
    case StreamSequencer::Verdict::kRestart:
      new_server = true;
      break;
    case StreamSequencer::Verdict::kAccepted:
      // The server numbers its models 1, 2, …: a jump is models lost on the way.
      if (previous != 0 && msg.seq() > previous + 1) {
        stats_.missed.fetch_add(msg.seq() - previous - 1, std::memory_order_relaxed);
      }
      break;
  }
  if (new_server) {
    ++epoch_;
    stats_.restarts.fetch_add(1, std::memory_order_relaxed);
  }
  staging_.receive_ns = receive_ns;
  staging_.tool_seq = msg.tool_seq();
  staging_.epoch = epoch_;
  model_box_.Write(staging_);
  last_accept_ns_ = receive_ns;
  refused_since_warn_.fill(0);  // the silence, if one comes, starts here
  stats_.accepted.fetch_add(1, std::memory_order_relaxed);
}

void HapticClientLink::ExplainSilence(int64_t now_ns) {
  const int64_t silent_ns = now_ns - last_accept_ns_;
  if (silent_ns < options_.silence_ns || now_ns - last_silence_warn_ns_ < kLinkWarnPeriodNs) return;
  auto n = [this](PacketReason r) { return refused_since_warn_[static_cast<size_t>(r)]; };
  uint64_t refused = 0;
  for (const uint64_t v : refused_since_warn_) refused += v;
  if (refused > 0) {
    const double window_s = 1e-9 * static_cast<double>(now_ns - std::max(last_silence_warn_ns_, last_accept_ns_));
    const bool unsigned_only = n(PacketReason::kUnsigned) == refused;
    Log().warn("models on {} are not authentic: {} forged, {} unsigned, {} replayed, {} outside the window, {} "
               "invalid epoch, {} from another server, {} other refusals in the last {:.1f} s; no authentic model "
               "for {:.1f} s, so the force fades to zero{}",
               model_channel_, n(PacketReason::kForged), n(PacketReason::kUnsigned), n(PacketReason::kReplayed),
               n(PacketReason::kOutsideWindow), n(PacketReason::kInvalidEpoch), n(PacketReason::kOtherSender),
               refused - n(PacketReason::kForged) - n(PacketReason::kUnsigned) - n(PacketReason::kReplayed) -
                   n(PacketReason::kOutsideWindow) - n(PacketReason::kInvalidEpoch) -
                   n(PacketReason::kOtherSender),
               window_s, 1e-9 * static_cast<double>(silent_ns),
               unsigned_only ? " (is the server running without the session key?)" : "");
  }
  refused_since_warn_.fill(0);
  last_silence_warn_ns_ = now_ns;
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

bool HapticClientLink::TakeModel(ReceivedModel* out) noexcept {
  if (!model_box_.Read(out)) return false;
  packets_.Add(PacketReason::kAccepted);
  return true;
}

HapticClientLinkStats HapticClientLink::stats() const {
  HapticClientLinkStats s;
  s.tools_written = stats_.tools_written.load();
  s.tools_published = stats_.tools_published.load();
  s.tools_not_sent = stats_.tools_not_sent.load();
  const uint64_t handled = s.tools_published + s.tools_not_sent;
  s.tools_coalesced = s.tools_written > handled ? s.tools_written - handled : 0;
  s.models_received = stats_.models_received.load();
  s.models_superseded = stats_.models_superseded.load();
  s.decode_errors = stats_.decode_errors.load() + stats_.subscription_errors.load();
  s.foreign_session = stats_.foreign_session.load();
  s.stale = stats_.stale.load();
  s.duplicate = stats_.duplicate.load();
  s.malformed = stats_.malformed.load();
  s.restarts = stats_.restarts.load();
  s.accepted = stats_.accepted.load();
  s.missed = stats_.missed.load();
  s.waits = stats_.waits.load();
  s.packets = SnapshotPackets(packets_, s.accepted, receiver_.get());
  if (receiver_ != nullptr) s.models_superseded = s.packets[PacketReason::kSuperseded];
  return s;
}

FaultStats HapticClientLink::publish_fault_stats() const { return publisher_->injector().stats(); }

FaultStats HapticClientLink::receive_fault_stats() const {
  return receive_faults_ != nullptr ? receive_faults_->stats() : FaultStats{};
}

}  // namespace cutsim::transport

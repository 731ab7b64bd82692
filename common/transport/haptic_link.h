#pragma once
/// @file
/// The haptic link over LCM: tool poses up (`CUTSIM_<session>_TOOL`, haptic
/// station → server, up to 1 kHz) and local models down
/// (`CUTSIM_<session>_MODEL`, one per physics frame).
///
/// Every message carries the sender's sequence number (from 1, +1 per
/// message) and its CLOCK_MONOTONIC stamp. Receivers keep only the newest:
/// `StreamSequencer` drops duplicates and out-of-order messages, and
/// recognises a restarted sender (seq back to a small number) so that a
/// server or client restart is resumed, not ignored for seconds:
///
/// * seq above the held one → accepted;
/// * seq equal → duplicate (dropped);
/// * seq below, with a *newer* stamp than the held message, or more than
///   `restart_window` below → the sender restarted (accepted, counted). A
///   reordered or replayed message carries an older stamp from the same
///   clock, so it is stale (dropped). Stamps are only compared with stamps of
///   the same sender, never with our clock.
///
/// Messages from another session (the `session` field; channels are per
/// session already, so this is a misconfigured or hostile sender), garbage
/// (decode errors, counted by the bus), and tool poses with non-finite or
/// absurd values are dropped and counted. Models are converted here but
/// *validated* by the renderer (`haptics::Validate`), which counts NaN and
/// malformed models; a model whose stiffness is not 3×3 is dropped here.
///
/// Threading:
/// * `HapticServerLink` lives on the server's physics thread. Without
///   `StartReceiving`, `PollTool` reads pending tool packets (udpm
///   receiver) or handles pending LCM traffic with a 0 ms wait on that
///   thread. That is not enough for a fresh pose: on LCM's subscription one
///   message waits per subscription and *later* arrivals are dropped until
///   it is handled, so polling once per 5 ms frame hands the physics the
///   *oldest* pose since the previous frame. With
///   `StartReceiving` a receive thread dispatches every pose as it arrives
///   into a wait-free mailbox, and `PollTool` only takes the newest one
///   (late pose sampling: call it right before the step). Models are still
///   published from the physics thread (see lcm_bus.h on concurrency).
/// * `HapticClientLink` runs the bus on its own LCM thread (`Start`). The
///   1 kHz loop only touches two wait-free mailboxes (`PublishTool` writes
///   the newest tool sample, `TakeModel` reads the newest model) and, per
///   tool sample, one non-blocking `write` to an eventfd (`WakeFd`) that
///   wakes the LCM thread, which sends the sample at once (it waits in
///   `poll` on its udpm receiver's socket, or LCM's descriptor, and the
///   eventfd, not in a timed `lcm_handle_timeout` poll). So the loop never blocks or allocates for
///   the link, and a pose leaves as soon as the LCM thread is scheduled.
/// * Both ends' LCM threads can run SCHED_FIFO below the haptic loop
///   (realtime_thread.h).
///
/// Access control (with a session key; without one the session is open):
/// * tool poses: the client signs every tool message (`ToolAuthenticator`,
///   tool_auth.h) and the server's receive thread checks it before the pose
///   can reach the mailbox;
/// * models: the server signs every `HapticModel` with a trailer over its
///   serialised bytes (`PayloadAuthenticator`, domain `kHapticModelDomain`)
///   and its epoch (its CLOCK_REALTIME at start), sequence and signing time;
///   the client's LCM thread checks the trailer on the raw bytes before it
///   parses them, then their freshness (`EpochGate`, 2 s window), so only
///   authentic, fresh models reach the servo loop. A restarted server (a
///   newer epoch) is followed at once; models of an older epoch while the
///   followed server is alive are refused (other-sender) and the client
///   logs that two servers publish the session. When no authentic model
///   arrived for `silence_ns` (the watchdog) but refused ones did, the LCM
///   thread logs why, once a second; the servo loop's watchdog fades the
///   force as for a lost server.
///
/// Receiving: on `udpm://` URLs each end reads its channel through its own
/// socket (`UdpmReceiver`, udpm_receiver.h), so every datagram is judged and
/// counted (`PacketCounts`: exactly one `PacketReason` each) before anything
/// queues it, and a flood of junk cannot displace genuine messages from a
/// queue. Other URLs (memq:// in tests) keep LCM's subscription, which
/// queues one message before the link sees it and is counted per delivery.

#include <array>
#include <atomic>
#include <cstdint>
#include <memory>
#include <optional>
#include <string>
#include <thread>

#include <Eigen/Core>

#include "common/core/tool_pose.h"
#include "common/haptics/local_model.h"
#include "common/transport/fault_injection.h"
#include "common/transport/lcm_bus.h"
#include "common/transport/lcm_packet.h"
#include "common/transport/mailbox.h"
#include "common/transport/stream_auth.h"
#include "common/transport/udpm_receiver.h"
#include "common/transport/wake_fd.h"
#include "cutsim/v1/wire.pb.h"

namespace cutsim::transport {

/// Domain of the model stream's tags (`PayloadAuthenticator`).
inline constexpr const char* kHapticModelDomain = "cutsim.v1.HapticModel/hmac-sha256/1";

/// One tool pose as it travels up the link.
struct ToolSample {
  uint64_t seq = 0;        ///< Sender's sequence number (assigned by `HapticClientLink::PublishTool`).
  int64_t stamp_ns = 0;    ///< Sender's CLOCK_MONOTONIC when the device was read, ns.
  int64_t receive_ns = 0;  ///< Receiver's CLOCK_MONOTONIC at acceptance, ns (0 on the sending side).
  ToolPose pose;           ///< The tool in the world frame.
  Eigen::Vector3d velocity = Eigen::Vector3d::Zero();  ///< m/s, of the tip.
  uint32_t buttons = 0;    ///< bit 0: cutting enabled.
};

/// Newest-by-sequence filter with restart detection (see the file comment).
class StreamSequencer {
 public:
  enum class Verdict : uint8_t { kAccepted, kRestart, kDuplicate, kStale };
  static constexpr uint64_t kDefaultRestartWindow = 1000;

  explicit StreamSequencer(uint64_t restart_window = kDefaultRestartWindow)
      : restart_window_(restart_window) {}

  /// Classifies a message; kAccepted and kRestart make it the held one.
  Verdict Offer(uint64_t seq, int64_t stamp_ns) noexcept;
  /// Forgets the held message.
  void Reset() noexcept { have_ = false; }
  [[nodiscard]] bool has_value() const { return have_; }
  [[nodiscard]] uint64_t seq() const { return have_ ? seq_ : 0; }

 private:
  uint64_t restart_window_;
  bool have_ = false;
  uint64_t seq_ = 0;
  int64_t stamp_ns_ = 0;
};

/// Authenticates tool messages (HMAC in `ToolState.hmac`; the implementation
/// is `HmacToolAuthenticator` in tool_auth.h). Called on the sending and
/// receiving threads; implementations must not throw.
class ToolAuthenticator {
 public:
  virtual ~ToolAuthenticator() = default;
  /// Fills `msg->hmac` and the fields it needs (epoch, wall stamp); the other
  /// fields are final.
  virtual void Sign(v1::ToolState* msg) noexcept = 0;
  /// Checks `msg` (tag and freshness) and, if accepted, remembers it.
  [[nodiscard]] virtual AuthVerdict Verify(const v1::ToolState& msg) noexcept = 0;
};

/// Options shared by both ends.
struct HapticLinkOptions {
  FaultConfig publish_faults;        ///< Applied to what this end sends.
  FaultConfig receive_faults;        ///< Applied to what this end receives (before filtering).
  uint64_t restart_window = StreamSequencer::kDefaultRestartWindow;
  ToolAuthenticator* authenticator = nullptr;  ///< Not owned; null = no authentication.
  /// Models: the server signs with it, the client checks with it. Not
  /// owned; null = models are not authenticated.
  PayloadAuthenticator* model_auth = nullptr;
  int64_t model_window_ns = EpochGate::kDefaultWindowNs;  ///< Client: signing-time window of models.
  int64_t silence_ns = 100'000'000;  ///< Client: no authentic model this long → log why (the watchdog).
};

/// Server-side counters.
struct HapticServerLinkStats {
  uint64_t received = 0;         ///< Tool messages LCM delivered (including superseded ones).
  uint64_t superseded = 0;       ///< Replaced by a newer arrival before the poll (not an error).
  uint64_t decode_errors = 0;    ///< Garbage: oversized or not a ToolState.
  uint64_t accepted = 0;         ///< Valid, newest: returned by `PollTool`.
  uint64_t foreign_session = 0;  ///< `session` field not ours.
  uint64_t stale = 0;            ///< Out of order (older than the held one).
  uint64_t duplicate = 0;        ///< Same seq as the held one.
  uint64_t invalid = 0;          ///< Non-finite or absurd pose.
  uint64_t unauthenticated = 0;  ///< Failed `ToolAuthenticator::Verify` (sum of the next four).
  uint64_t auth_unsigned = 0;    ///< No tag while a key is configured.
  uint64_t auth_forged = 0;      ///< Bad tag.
  uint64_t auth_replayed = 0;    ///< Valid tag, but not fresh: sequence not newer, timestamp outside
                                 ///< the window, invalid epoch, or another sender holds the stream.
  uint64_t auth_outside_window = 0;  ///< Of `auth_replayed`: outside the window or invalid epoch.
  uint64_t restarts = 0;         ///< Client restarts detected (included in accepted).
  uint64_t models_published = 0;
  uint64_t models_not_sent = 0;  ///< Over one datagram or LCM refused.
  PacketCounts packets;          ///< Every tool packet by reason (per datagram on udpm).
};

/// The server's end: polls tool poses, publishes local models.
class HapticServerLink {
 public:
  /// Subscribes to `CUTSIM_<session>_TOOL` on `bus`. Throws `InputError`
  /// (field "--session") on an invalid session name and for invalid fault
  /// settings. `bus` must outlive the link and belongs to the caller's thread
  /// (until `StartReceiving`).
  HapticServerLink(LcmBus& bus, std::string session, HapticLinkOptions options = {});
  ~HapticServerLink();  ///< Stops the receive thread.
  HapticServerLink(const HapticServerLink&) = delete;
  HapticServerLink& operator=(const HapticServerLink&) = delete;

  /// Starts the receive thread, which from now on owns the bus's receiving
  /// side (it dispatches every subscription on the bus): each tool pose is
  /// checked as it arrives and the newest valid one waits in a mailbox.
  /// `rt_priority` > 0: the thread tries SCHED_FIFO at that priority and
  /// logs a warning if not permitted. Idempotent.
  void StartReceiving(int rt_priority = 0);
  /// Stops and joins the receive thread (idempotent); `PollTool` polls again.
  void StopReceiving();
  [[nodiscard]] bool receiving() const { return receive_thread_.joinable(); }

  /// Non-blocking: returns the newest valid tool pose accepted since the
  /// previous call, or nullopt if none was. Without a receive thread it
  /// first handles pending LCM traffic with a 0 ms wait (this dispatches
  /// every subscription on the bus); with one it only reads the mailbox
  /// (no system call). The last accepted pose stays available as
  /// `latest_tool()`. Never throws for anything received.
  std::optional<ToolSample> PollTool();

  /// Publishes `model` on `CUTSIM_<session>_MODEL`. The link numbers the
  /// stream (seq 1, 2, ... of this link; `model.seq` is ignored) and stamps
  /// it with CLOCK_MONOTONIC now (`model.stamp_ns` is ignored); `tool_seq`
  /// is the seq of the tool pose the model was computed from (0 = none), so
  /// the client can measure pose-to-model latency. Never throws; a model
  /// over one datagram is not sent and counted (cannot happen: ~400 bytes).
  void PublishModel(const haptics::LocalModel& model, uint64_t tool_seq);

  /// Counters (each atomic; callable from the physics thread while receiving).
  [[nodiscard]] HapticServerLinkStats stats() const;
  [[nodiscard]] const std::optional<ToolSample>& latest_tool() const { return latest_; }
  [[nodiscard]] uint64_t last_model_seq() const { return model_seq_; }
  /// Whether models carry the session key's tag.
  [[nodiscard]] bool signs_models() const { return options_.model_auth != nullptr; }
  /// Whether tool packets are read by the packet-level receiver (udpm).
  [[nodiscard]] bool packet_level() const { return receiver_ != nullptr; }
  [[nodiscard]] const std::string& session() const { return session_; }

 private:
  void OnToolBytes(std::span<const uint8_t> bytes, int64_t receive_ns);
  void ProcessToolBytes(std::span<const uint8_t> bytes, int64_t receive_ns);
  void ProcessTool(const v1::ToolState& msg, int64_t receive_ns);
  /// Waits for the receiver's (or LCM's) descriptor or the wake-up.
  bool WaitForInput(int timeout_ms);
  /// Receiving side: handle LCM (0 ms), release fault-delayed poses, mirror counters.
  void ReceivePending();

  LcmBus& bus_;
  std::string session_;
  HapticLinkOptions options_;
  std::string tool_channel_;
  std::string model_channel_;
  // Receiving side (the receive thread, or the PollTool caller without one).
  StreamSequencer sequencer_;
  v1::ToolState scratch_;      // reused: each tool message is decoded into it
  std::unique_ptr<FaultInjector> receive_faults_;  // null when inactive
  // Physics-thread side.
  std::optional<ToolSample> latest_;
  uint64_t model_seq_ = 0;
  v1::HapticModel model_msg_;  // reused
  uint64_t model_epoch_;        // CLOCK_REALTIME at start, ns: the signed models' epoch
  std::array<uint8_t, kLcmMaxPayloadBytes + kTrailerBytes> model_bytes_{};  // serialised + trailer
  std::unique_ptr<FaultyLcmPublisher> publisher_;
  // Shared.
  Mailbox<ToolSample> tool_box_;
  struct AtomicStats {
    std::atomic<uint64_t> received{0}, superseded{0}, decode_errors{0}, accepted{0}, foreign_session{0},
        stale{0}, duplicate{0}, invalid{0}, unauthenticated{0}, auth_unsigned{0}, auth_forged{0},
        auth_replayed{0}, auth_outside_window{0}, restarts{0}, models_published{0}, models_not_sent{0},
        subscription_errors{0};
  } stats_;
  PacketCounters packets_;
  std::unique_ptr<UdpmReceiver> receiver_;  // udpm URLs; else `subscription_`
  WakeFd wake_;  // stops the receive thread's poll
  std::atomic<bool> receive_running_{false};
  std::thread receive_thread_;
  LcmSubscription subscription_;  // last: unsubscribes first
};

/// A model as the haptic loop receives it.
struct ReceivedModel {
  haptics::LocalModel model;
  int64_t receive_ns = 0;  ///< Our CLOCK_MONOTONIC when the LCM thread accepted it, ns.
  uint64_t tool_seq = 0;   ///< Seq of the tool pose the server used (0 = none).
  uint64_t epoch = 0;      ///< +1 each time the server's stream restarts: reset the renderer.
};

/// Client-side counters (a consistent-enough snapshot; each is atomic).
struct HapticClientLinkStats {
  uint64_t tools_written = 0;     ///< `PublishTool` calls by the loop.
  uint64_t tools_published = 0;   ///< Sent (or handed to the fault injector).
  uint64_t tools_coalesced = 0;   ///< Overwritten in the mailbox before the LCM thread sent them.
  uint64_t tools_not_sent = 0;    ///< LCM refused.
  uint64_t models_received = 0;   ///< Delivered by LCM (including superseded).
  uint64_t models_superseded = 0;
  uint64_t decode_errors = 0;     ///< Garbage.
  uint64_t foreign_session = 0;
  uint64_t stale = 0;
  uint64_t duplicate = 0;
  uint64_t malformed = 0;         ///< Stiffness not 3×3.
  uint64_t restarts = 0;          ///< Server restarts detected.
  uint64_t accepted = 0;          ///< Handed to the mailbox.
  uint64_t missed = 0;            ///< Gaps in the accepted models' sequence (lost on the way).
  uint64_t waits = 0;             ///< Waits the LCM thread began, each counted before it blocks.
  PacketCounts packets;           ///< Every model packet by reason (per datagram on udpm).
};

/// The haptic station's end.
class HapticClientLink {
 public:
  /// Subscribes to `CUTSIM_<session>_MODEL` on `bus`. After `Start` the bus
  /// belongs to the link's LCM thread until `Stop`. Throws `InputError` on an
  /// invalid session name or fault settings.
  HapticClientLink(LcmBus& bus, std::string session, HapticLinkOptions options = {});
  ~HapticClientLink();  ///< Stops the thread.
  HapticClientLink(const HapticClientLink&) = delete;
  HapticClientLink& operator=(const HapticClientLink&) = delete;

  /// Starts the LCM thread: sends each tool sample as soon as `PublishTool`
  /// wakes it, receives models, releases fault-delayed messages; it waits
  /// at most `wait_ms` per round (a bound for housekeeping, not a polling
  /// period: poses and models wake it). `rt_priority` > 0: the thread tries
  /// SCHED_FIFO at that priority (below the haptic loop's) and logs a
  /// warning if not permitted.
  void Start(int wait_ms = 100, int rt_priority = 0);
  /// Stops and joins the LCM thread (idempotent).
  void Stop();
  /// One round of the LCM thread (send the newest tool sample, wait up to
  /// `wait_ms` for an LCM message or a `PublishTool` wake-up, dispatch,
  /// release delayed messages, send the newest tool sample). For tests that
  /// drive the link from their own thread instead of `Start`. Returns
  /// models accepted.
  int RunOnce(int wait_ms);

  // ---- Real-time side (one thread: the haptic loop). Never blocks. -------
  /// Hands a tool sample to the LCM thread and wakes it (one non-blocking
  /// eventfd write); assigns and returns its seq (`sample.seq` is ignored;
  /// `sample.stamp_ns` 0 means now).
  uint64_t PublishTool(const ToolSample& sample) noexcept;
  /// If a model newer than the last taken one arrived, copies it to `*out`.
  bool TakeModel(ReceivedModel* out) noexcept;

  [[nodiscard]] HapticClientLinkStats stats() const;
  [[nodiscard]] const std::string& session() const { return session_; }
  /// Whether models are checked against the session key.
  [[nodiscard]] bool authenticates_models() const { return options_.model_auth != nullptr; }
  /// Counters of the fault injectors (LCM-thread data: read after `Stop`).
  [[nodiscard]] FaultStats publish_fault_stats() const;
  [[nodiscard]] FaultStats receive_fault_stats() const;

 private:
  void OnModelBytes(std::span<const uint8_t> bytes, int64_t receive_ns);
  void ProcessModelBytes(std::span<const uint8_t> bytes, int64_t receive_ns);
  /// The authentication of one model's bytes: true with `*body` set, else counted.
  bool Authenticate(std::span<const uint8_t> bytes, std::span<const uint8_t>* body);
  void Refuse(PacketReason reason);
  void ProcessModel(const v1::HapticModel& msg, int64_t receive_ns);
  void SendPendingTool(int64_t now_ns);
  /// Logs (at most once a second) why no authentic model arrives.
  void ExplainSilence(int64_t now_ns);

  LcmBus& bus_;
  std::string session_;
  HapticLinkOptions options_;
  std::string tool_channel_;
  std::string model_channel_;
  // LCM-thread state.
  StreamSequencer sequencer_;
  EpochGate gate_;
  uint64_t epoch_ = 0;
  int64_t last_accept_ns_ = 0;         // CLOCK_MONOTONIC of the last accepted model (or the start)
  int64_t last_silence_warn_ns_ = 0;
  int64_t last_two_servers_warn_ns_ = 0;
  std::array<uint64_t, kPacketReasonCount> refused_since_warn_{};  // since the last accepted model or warning
  v1::ToolState tool_msg_;     // reused
  v1::HapticModel scratch_;    // reused: each model is decoded into it
  ReceivedModel staging_;
  std::unique_ptr<FaultInjector> receive_faults_;
  std::unique_ptr<FaultyLcmPublisher> publisher_;
  // Shared.
  Mailbox<ToolSample> tool_box_;
  Mailbox<ReceivedModel> model_box_;
  WakeFd wake_;                 // PublishTool and Stop → LCM thread
  uint64_t next_tool_seq_ = 0;  // RT-thread only
  struct AtomicStats {
    std::atomic<uint64_t> tools_written{0}, tools_published{0}, tools_not_sent{0},
        models_received{0}, models_superseded{0}, decode_errors{0}, foreign_session{0}, stale{0},
        duplicate{0}, malformed{0}, restarts{0}, accepted{0}, subscription_errors{0}, missed{0}, waits{0};
  } stats_;
  PacketCounters packets_;
  std::unique_ptr<UdpmReceiver> receiver_;  // udpm URLs; else `subscription_`
  std::atomic<bool> running_{false};
  std::thread thread_;
  LcmSubscription subscription_;  // last: unsubscribes first
};

/// Conversions between the wire and the haptics types (exposed for tests and
/// tools). `FromProto` returns false if the stiffness is present but not 9
/// entries; everything else is left to `haptics::Validate`.
void ToProto(const haptics::LocalModel& model, v1::HapticModel* msg);
[[nodiscard]] bool FromProto(const v1::HapticModel& msg, haptics::LocalModel* model) noexcept;
void ToProto(const ToolSample& sample, v1::ToolState* msg);
[[nodiscard]] ToolSample FromProto(const v1::ToolState& msg) noexcept;

}  // namespace cutsim::transport

#pragma once
/// @file
/// The haptic link's bus: RAII over LCM's C API carrying protobuf messages.
///
/// Receiving is "newest wins", because a stale force or pose is worse than
/// none. Each subscription holds at most one pending message: LCM's own
/// queue for it has capacity 1 (`lcm_subscription_set_queue_capacity`), and
/// when several messages for it are dispatched during one `HandleTimeout`,
/// each replaces the previous pending one (counted as superseded). After
/// LCM returns, `HandleTimeout` decodes each pending message once and calls
/// the subscriber. So the C callback only copies bytes into a buffer sized
/// for the type's limit (no allocation once warm, never throws), and a
/// subscriber's exception leaves `HandleTimeout` after LCM is out of the way.
///
/// Note on LCM's capacity: under `udpm://` LCM's receive thread drops
/// *arrivals* while a message is pending, so the one delivered can be as old
/// as the caller's handling period; call `HandleTimeout` at least as often
/// as messages are produced and compare sequence numbers (`LatestSlot`).
///
/// Note on `udpm://` and loopback: LCM joins its multicast group on the
/// interface the routing table picks. With TTL 0 no datagram leaves the host,
/// but unless the group is routed via `lo` the kernel sends IGMP membership
/// reports on that interface. `LcmBus` logs a warning when it sees this; the
/// fix is a host route (`ip route add 239.255.76.67/32 dev lo`).
///
/// Threading: one thread owns a bus and its subscriptions and calls
/// `HandleTimeout`. At most one *other* thread may call `Publish` and
/// `PublishBytes` concurrently (the server publishes local models from its
/// physics thread while its LCM thread receives): `lcm_publish` is
/// thread-safe, and the publishing state here (encoder, publish counters) is
/// disjoint from the handling state. `Subscribe`, unsubscribing and `stats()`
/// only while no other thread uses the bus.

#include <cstddef>
#include <cstdint>
#include <functional>
#include <memory>
#include <span>
#include <string>
#include <string_view>
#include <utility>
#include <vector>

#include <google/protobuf/message_lite.h>

#include "common/transport/channels.h"
#include "common/transport/codec.h"

namespace cutsim::transport {

/// Throws `InputError` naming `field` unless `url` is a URL LCM can open
/// without aborting: provider://address?options; for udpm an IPv4 multicast
/// group, a port in [1, 65535], ttl in [0, 255] and recv_buf_size > 0 (no
/// other options); for tcpq a port in [1, 65535]; providers udpm, mpudpm,
/// memq, tcpq, file. `LcmBus` calls it before `lcm_create`.
void ValidateLcmUrl(std::string_view url, std::string_view field = "--lcm-url");

class LcmBus;

/// Counters of one subscription.
struct LcmSubscriptionStats {
  uint64_t received = 0;       ///< Messages LCM handed to us.
  uint64_t delivered = 0;      ///< Decoded and passed to the callback.
  uint64_t superseded = 0;     ///< Replaced by a newer one before delivery (stale, dropped).
  uint64_t decode_errors = 0;  ///< Too large or malformed; dropped.
};

/// Counters of a bus.
struct LcmBusStats {
  uint64_t published = 0;
  uint64_t publish_too_large = 0;  ///< Refused: over the bus's datagram limit.
  uint64_t publish_failed = 0;     ///< Encoding failed or LCM refused to send.
  uint64_t handle_errors = 0;      ///< lcm_handle_timeout reported an error.
};

/// Result of `LcmBus::Publish`.
enum class PublishStatus : uint8_t {
  kOk = 0,
  kTooLarge,  ///< Encoded size above the bus's limit; nothing sent.
  kFailed,    ///< Encoding or sending failed; nothing (or not all) sent.
};

namespace detail {

/// Type-erased state of one subscription; owned by `LcmSubscription`,
/// registered with its bus for dispatch. Address-stable (heap allocated)
/// because LCM holds a pointer to it.
class LcmSubscriptionState {
 public:
  LcmSubscriptionState(std::string channel, size_t max_bytes, std::string_view type_name)
      : channel_(std::move(channel)), max_bytes_(max_bytes), type_name_(type_name) {}
  virtual ~LcmSubscriptionState() = default;
  LcmSubscriptionState(const LcmSubscriptionState&) = delete;
  LcmSubscriptionState& operator=(const LcmSubscriptionState&) = delete;

  /// Called from LCM's C callback: keeps a copy of the newest raw message.
  void Receive(const void* data, size_t size) noexcept;
  /// Decodes the pending message and calls the subscriber. Returns true if
  /// the callback ran. Exceptions from the callback propagate.
  bool DeliverPending();

  const std::string& channel() const { return channel_; }
  const LcmSubscriptionStats& stats() const { return stats_; }
  const DecodeError& last_error() const { return last_error_; }

 protected:
  /// Decodes `bytes` and calls the subscriber; returns false (filling `err`) on a bad payload.
  virtual bool DecodeAndCall(std::span<const uint8_t> bytes, DecodeError* err) = 0;

 private:
  friend class ::cutsim::transport::LcmBus;
  std::string channel_;
  size_t max_bytes_;
  std::string_view type_name_;    // static: owned by the protobuf descriptor pool
  std::vector<uint8_t> pending_;  // capacity grows to the largest message seen
  size_t pending_size_ = 0;
  bool has_pending_ = false;
  bool oversized_pending_ = false;
  size_t oversized_size_ = 0;
  LcmSubscriptionStats stats_;
  DecodeError last_error_;
  void* lcm_subscription_ = nullptr;  // lcm_subscription_t*
  int64_t last_warn_ns_ = 0;          // rate limit for decode-error warnings
};

/// Hands the raw payload to the subscriber, undecoded: for a receiver that
/// authenticates the bytes before it parses them (haptic_link.h).
class RawLcmSubscriptionState final : public LcmSubscriptionState {
 public:
  RawLcmSubscriptionState(std::string channel, size_t max_bytes,
                          std::function<void(std::span<const uint8_t>)> callback)
      : LcmSubscriptionState(std::move(channel), max_bytes, "bytes"), callback_(std::move(callback)) {}

 protected:
  bool DecodeAndCall(std::span<const uint8_t> bytes, DecodeError* /*err*/) override {
    callback_(bytes);
    return true;
  }

 private:
  std::function<void(std::span<const uint8_t>)> callback_;
};

template <class Msg>
class TypedLcmSubscriptionState final : public LcmSubscriptionState {
 public:
  TypedLcmSubscriptionState(std::string channel, std::function<void(const Msg&)> callback)
      : LcmSubscriptionState(std::move(channel), MaxPayloadBytes<Msg>(),
                             Msg::descriptor()->full_name()),
        callback_(std::move(callback)) {}

 protected:
  bool DecodeAndCall(std::span<const uint8_t> bytes, DecodeError* err) override {
    if (!DecodeInto(bytes, msg_, channel(), err)) return false;
    callback_(msg_);
    return true;
  }

 private:
  Msg msg_;  // reused for every message
  std::function<void(const Msg&)> callback_;
};

}  // namespace detail

/// An active subscription; unsubscribes when destroyed. Must not outlive its bus.
class LcmSubscription {
 public:
  LcmSubscription() = default;
  ~LcmSubscription();
  LcmSubscription(LcmSubscription&& other) noexcept
      : bus_(std::exchange(other.bus_, nullptr)), state_(std::move(other.state_)) {}
  LcmSubscription& operator=(LcmSubscription&& other) noexcept;
  LcmSubscription(const LcmSubscription&) = delete;
  LcmSubscription& operator=(const LcmSubscription&) = delete;

  [[nodiscard]] bool active() const { return state_ != nullptr; }
  [[nodiscard]] const std::string& channel() const;
  [[nodiscard]] const LcmSubscriptionStats& stats() const;
  /// The most recent decode error (status kOk if none yet).
  [[nodiscard]] const DecodeError& last_error() const;

 private:
  friend class LcmBus;
  LcmSubscription(LcmBus* bus, std::unique_ptr<detail::LcmSubscriptionState> state)
      : bus_(bus), state_(std::move(state)) {}
  void Release() noexcept;

  LcmBus* bus_ = nullptr;
  std::unique_ptr<detail::LcmSubscriptionState> state_;
};

/// One LCM instance (`lcm_t`).
class LcmBus {
 public:
  /// Opens LCM at `url` ("udpm://group:port?ttl=0", "memq://", "file://...").
  /// Throws `InputError` naming `--lcm-url` if LCM cannot be created with it.
  /// `max_payload_bytes` bounds what `Publish` sends (default: one datagram).
  explicit LcmBus(std::string_view url = kDefaultLcmUrl,
                  size_t max_payload_bytes = kLcmMaxPayloadBytes);
  ~LcmBus();
  LcmBus(const LcmBus&) = delete;
  LcmBus& operator=(const LcmBus&) = delete;
  LcmBus(LcmBus&&) = delete;
  LcmBus& operator=(LcmBus&&) = delete;

  /// Encodes and sends `msg`. Refuses (kTooLarge, with a warning at most
  /// once per second) when the encoding exceeds the bus's limit. Never throws.
  PublishStatus Publish(std::string_view channel, const google::protobuf::MessageLite& msg) noexcept;

  /// Sends raw bytes as they are (for tools and tests). Never throws.
  PublishStatus PublishBytes(std::string_view channel, std::span<const uint8_t> bytes) noexcept;

  /// Subscribes to one channel (an exact name; validated so it cannot act
  /// as a regular expression). `callback` runs inside `HandleTimeout` with
  /// the newest decoded message; it must not destroy its own subscription.
  /// Throws `InputError` on an invalid channel.
  template <class Msg>
  [[nodiscard]] LcmSubscription Subscribe(std::string channel,
                                          std::function<void(const Msg&)> callback) {
    return Register(std::make_unique<detail::TypedLcmSubscriptionState<Msg>>(
        std::move(channel), std::move(callback)));
  }

  /// As `Subscribe`, but `callback` gets the newest payload's bytes as they
  /// arrived (at most `max_bytes`; larger ones are dropped and counted as
  /// decode errors), valid during the call.
  [[nodiscard]] LcmSubscription SubscribeRaw(std::string channel, size_t max_bytes,
                                             std::function<void(std::span<const uint8_t>)> callback) {
    return Register(std::make_unique<detail::RawLcmSubscriptionState>(std::move(channel), max_bytes,
                                                                      std::move(callback)));
  }

  /// Waits up to `timeout_ms` (≥ 0) for a message, then dispatches everything
  /// already queued without further waiting, and finally delivers the newest
  /// pending message of each subscription. Returns the number of callbacks
  /// run. Never blocks longer than `timeout_ms` plus the callbacks' time.
  int HandleTimeout(int timeout_ms);

  /// LCM's notification descriptor (`lcm_get_fileno`): readable when a
  /// message is queued, so that `HandleTimeout(0)` will dispatch it. For a
  /// thread that waits in `poll` on it and on other descriptors (a
  /// `WakeFd`) instead of in `HandleTimeout`. Owner thread only.
  [[nodiscard]] int fileno() const;

  [[nodiscard]] const std::string& url() const { return url_; }
  [[nodiscard]] const LcmBusStats& stats() const { return stats_; }
  /// Sum of all live subscriptions' decode errors plus those of closed ones.
  [[nodiscard]] uint64_t decode_errors() const;
  /// Sum of all subscriptions' received messages (live and closed).
  [[nodiscard]] uint64_t received() const;

 private:
  friend class LcmSubscription;
  LcmSubscription Register(std::unique_ptr<detail::LcmSubscriptionState> state);
  void Unregister(detail::LcmSubscriptionState* state) noexcept;

  std::string url_;
  size_t max_payload_bytes_;
  void* lcm_ = nullptr;  // lcm_t*; kept opaque so users need no LCM headers
  Encoder encoder_;
  std::vector<detail::LcmSubscriptionState*> subscriptions_;
  LcmBusStats stats_;
  uint64_t closed_decode_errors_ = 0;
  uint64_t closed_received_ = 0;
  int64_t last_publish_warn_ns_ = 0;
};

}  // namespace cutsim::transport

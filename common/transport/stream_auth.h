#pragma once
/// @file
/// Authentication of the session's streams with the session key: the tool
/// stream (haptic station → server), the model stream (server → haptic
/// station) and the observer stream (server → viewers).
///
/// Two pieces, used by every stream:
///
/// * **A tag over the bytes as sent.** `PayloadAuthenticator` signs a
///   serialised protobuf message by appending one field, `bytes hmac = 127`
///   (35 bytes: the key 0xFA 0x07, the length 32, the tag), whose value is
///   HMAC-SHA256(key, domain ‖ len(session) ‖ session ‖ body), body being
///   every byte before the trailer. The receiver checks the tag on the raw
///   bytes before it parses anything, so a forged message never reaches a
///   parser, a queue or a mailbox. Appending is valid protobuf (a field may
///   follow any other), so an unauthenticated reader still parses the message.
///   The domain names the message type and version, so a tag never moves
///   from one message kind to another, and the session binds it to one
///   session. Tags are compared in constant time (CRYPTO_memcmp).
///
/// * **Freshness by sender epoch.** Every signed message carries its sender's
///   epoch (CLOCK_REALTIME at the sender's start, ns, so a restarted sender's
///   epoch is larger), a sequence number rising within the epoch, and the
///   sender's CLOCK_REALTIME when it signed. `EpochGate` accepts an
///   authentic message when
///   - its epoch is not after its own signing time (an epoch from the future
///     is invalid: without this rule one message with a huge epoch would
///     hold the stream for good);
///   - its signing time is within `window` of the receiver's clock, when a
///     window is set (a recording replayed later is refused);
///   - it is newer than anything accepted from its epoch (replays are
///     refused);
///   - its epoch is the one the receiver follows, or a newer one (the sender
///     restarted), or the followed epoch has been quiet for `quiet` (its
///     sender is gone). So a message from another, older sender is refused
///     while the followed one is alive, and no single message can lock a
///     sender out for longer than `quiet`.
///
/// With no key configured (an open session) nothing is signed or checked;
/// the apps say so at start.

#include <array>
#include <cstddef>
#include <cstdint>
#include <optional>
#include <span>
#include <string>
#include <string_view>

namespace cutsim::transport {

/// Environment variable holding the hex session key.
inline constexpr const char* kSessionKeyEnv = "CUTSIM_SESSION_KEY";

/// A session key: 16..64 bytes.
struct SessionKey {
  static constexpr size_t kMinBytes = 16;
  static constexpr size_t kMaxBytes = 64;
  std::array<uint8_t, kMaxBytes> bytes{};
  size_t size = 0;
};

/// Parses hex text (whitespace ignored). Throws `InputError` naming `source`
/// (file or environment variable) on odd length, non-hex digits, or a key
/// shorter than 16 or longer than 64 bytes. The error never quotes the key.
[[nodiscard]] SessionKey ParseSessionKey(std::string_view text, std::string_view source);

/// The key from `key_file` if not empty (warns if the file is readable by
/// group or others), else from `CUTSIM_SESSION_KEY` if set, else nullopt (an
/// open session). Throws `InputError` naming the file or variable when it is
/// unreadable or malformed.
[[nodiscard]] std::optional<SessionKey> LoadSessionKey(const std::string& key_file);

/// CLOCK_REALTIME in ns.
[[nodiscard]] int64_t RealtimeNowNs() noexcept;

/// Outcome of authenticating one message.
enum class AuthVerdict : uint8_t {
  kOk,             ///< Authentic and fresh.
  kNewEpoch,       ///< Authentic and fresh, from a sender epoch the receiver now follows.
  kUnsigned,       ///< No tag.
  kForged,         ///< Tag of the wrong size or not matching (wrong key, altered, other session).
  kReplayed,       ///< Authentic, but not newer than a message already accepted from its epoch.
  kOutsideWindow,  ///< Authentic, but signed far from the receiver's clock (an old recording).
  kInvalidEpoch,   ///< Authentic, but its epoch is after its own signing time.
  kOtherSender,    ///< Authentic, from an older epoch while the followed sender is alive.
};

/// Name of a verdict for logs, counters and tests.
[[nodiscard]] const char* ToString(AuthVerdict verdict);

/// True for the verdicts that let a message through.
[[nodiscard]] constexpr bool Accepted(AuthVerdict v) {
  return v == AuthVerdict::kOk || v == AuthVerdict::kNewEpoch;
}

/// HMAC-SHA256 keyed once (OpenSSL libcrypto, EVP_MAC). One thread at a
/// time; never throws after construction.
class HmacSha256 {
 public:
  static constexpr size_t kTagBytes = 32;
  using Tag = std::array<uint8_t, kTagBytes>;

  /// Throws std::runtime_error if OpenSSL cannot set up HMAC-SHA256.
  explicit HmacSha256(const SessionKey& key);
  ~HmacSha256();
  HmacSha256(const HmacSha256&) = delete;
  HmacSha256& operator=(const HmacSha256&) = delete;

  /// Starts a new tag; then `Update` the parts and `Final`. False on an
  /// OpenSSL failure (the message is then treated as unsigned or forged).
  bool Begin() noexcept;
  bool Update(std::span<const uint8_t> bytes) noexcept;
  bool Final(Tag* tag) noexcept;

 private:
  void* mac_ = nullptr;  // EVP_MAC*
  void* ctx_ = nullptr;  // EVP_MAC_CTX*, keyed once; re-initialised per tag
};

/// Protobuf field number of the signed trailer in every signed message type;
/// no signed message uses it for anything else.
inline constexpr uint32_t kTrailerField = 127;
/// Size of the signed trailer: the field's key (two bytes of varint), the
/// length 32, and the tag.
inline constexpr size_t kTrailerBytes = 3 + HmacSha256::kTagBytes;

/// A message split into the bytes the tag covers and the tag.
struct SignedBytes {
  std::span<const uint8_t> body;
  std::span<const uint8_t> tag;  ///< Empty if the message carries no trailer.
};

/// Splits `bytes` at the trailer if its last 35 bytes are one.
[[nodiscard]] SignedBytes SplitTrailer(std::span<const uint8_t> bytes) noexcept;

/// Tags and checks serialised messages of one kind in one session.
class PayloadAuthenticator {
 public:
  /// `domain` names the message type and version, e.g.
  /// "cutsim.v1.HapticModel/hmac-sha256/1". Throws like `HmacSha256`.
  PayloadAuthenticator(const SessionKey& key, std::string domain, std::string session);

  /// The tag of `body` (false on an OpenSSL failure).
  bool TagOf(std::span<const uint8_t> body, HmacSha256::Tag* tag) noexcept;
  /// Writes the trailer for `body` into `out` (kTrailerBytes).
  bool MakeTrailer(std::span<const uint8_t> body, std::span<uint8_t, kTrailerBytes> out) noexcept;
  /// Checks the trailer of `bytes`: kOk with `*body` set to the covered
  /// bytes, kUnsigned or kForged. Freshness is the caller's (`EpochGate`).
  AuthVerdict Check(std::span<const uint8_t> bytes, std::span<const uint8_t>* body) noexcept;

 private:
  HmacSha256 mac_;
  std::string domain_;
  std::string session_;
};

/// Freshness of authentic messages by sender epoch (see the file comment).
/// Allocation-free; one thread.
class EpochGate {
 public:
  static constexpr int64_t kDefaultWindowNs = 2'000'000'000;
  static constexpr int64_t kDefaultQuietNs = 500'000'000;
  /// Epochs whose highest sequences are remembered (the followed one included).
  static constexpr size_t kEpochsKept = 8;
  /// Independent sequence spaces of one sender (the observer stream numbers
  /// its snapshot, delta and status topics separately).
  static constexpr size_t kLanes = 3;

  /// `window_ns` ≤ 0 turns the signing-time window off (streams that replay
  /// old keyframes to late joiners). `quiet_ns` is how long the followed
  /// epoch must be silent before an older one may take over.
  explicit EpochGate(int64_t window_ns = kDefaultWindowNs, int64_t quiet_ns = kDefaultQuietNs)
      : window_ns_(window_ns), quiet_ns_(quiet_ns) {}

  /// Judges an authentic message (epoch, seq in `lane`, signing time) at
  /// receiver times `now_wall_ns` (CLOCK_REALTIME) and `now_mono_ns`
  /// (CLOCK_MONOTONIC, for the quiet period); an accepted message is
  /// remembered. A lane ≥ kLanes is refused as kInvalidEpoch.
  AuthVerdict Offer(uint64_t epoch, uint64_t seq, int64_t wall_ns, int64_t now_wall_ns,
                    int64_t now_mono_ns, size_t lane = 0) noexcept;
  /// `Offer` in two steps, for a receiver that takes a message only once
  /// its content proved valid: `Judge` decides without remembering, and
  /// `Record` remembers a message judged acceptable.
  [[nodiscard]] AuthVerdict Judge(uint64_t epoch, uint64_t seq, int64_t wall_ns,
                                  int64_t now_wall_ns, int64_t now_mono_ns,
                                  size_t lane = 0) const noexcept;
  void Record(uint64_t epoch, uint64_t seq, int64_t now_mono_ns, size_t lane = 0) noexcept;

  /// The followed epoch, 0 before the first accepted message.
  [[nodiscard]] uint64_t epoch() const { return followed_; }
  /// Forgets everything (a new session).
  void Reset() noexcept { *this = EpochGate(window_ns_, quiet_ns_); }

 private:
  struct Seen {
    uint64_t epoch = 0;
    std::array<uint64_t, kLanes> seq{};
    std::array<bool, kLanes> has{};
    int64_t last_mono_ns = 0;
  };
  [[nodiscard]] const Seen* Find(uint64_t epoch) const noexcept;
  Seen* Slot(uint64_t epoch) noexcept;  // existing entry, else the least recently used

  int64_t window_ns_;
  int64_t quiet_ns_;
  uint64_t followed_ = 0;
  std::array<Seen, kEpochsKept> seen_{};
};

}  // namespace cutsim::transport

#pragma once
/// @file
/// Access control for the tool stream: only the haptic station
/// holding the session's secret key may drive the tool.
///
/// * Key: 16 to 64 random bytes written as hex (32 to 128 hex digits,
///   whitespace ignored), from a file (`--key-file FILE`) or from the
///   environment (`CUTSIM_SESSION_KEY`); the file wins. Make one with
///   `openssl rand -hex 32 > session.key` (mode 0600). Both ends must hold
///   the same key.
/// * Tag: HMAC-SHA256 (OpenSSL libcrypto, EVP_MAC) over a fixed canonical
///   encoding of the message — a domain string, the session name, the sender
///   epoch, the sequence number, both stamps, the pose (IEEE-754 bit
///   patterns, little endian) and the buttons — not over the protobuf bytes,
///   whose encoding is not canonical. The tag travels in `ToolState.hmac`.
///   Tags are compared in constant time (CRYPTO_memcmp).
/// * Replay: a sender picks its epoch (its CLOCK_REALTIME at start, ns, so a
///   restarted sender's epoch is larger) and numbers its messages strictly
///   increasing within it. The receiver accepts a message only if its epoch is
///   newer than the held one, or the same epoch with a larger sequence, and
///   only if its `wall_ns` stamp is within `window` of the receiver's
///   CLOCK_REALTIME (so a recording replayed after a server restart is
///   refused). Across machines this needs clocks synchronised to well within
///   the window (NTP/chrony in a lab; default window 2 s).
///
/// Threading: one authenticator per end; `Sign` (haptic station's LCM thread)
/// and `Verify` (server's physics thread) are each called from one thread.
/// Neither throws. In the steady state neither allocates beyond what
/// OpenSSL 3's HMAC re-initialisation does (it duplicates two digest
/// contexts per message; see tool_auth_test.cc, which counts them). Signing
/// runs on the link's LCM thread, never in the 1 kHz servo loop.

#include <array>
#include <cstddef>
#include <cstdint>
#include <optional>
#include <string>
#include <string_view>

#include "common/transport/haptic_link.h"
#include "common/transport/stream_auth.h"
#include "cutsim/v1/wire.pb.h"

namespace cutsim::transport {

/// HMAC-SHA256 signing and verification of `ToolState` (see the file comment).
class HmacToolAuthenticator final : public ToolAuthenticator {
 public:
  static constexpr size_t kTagBytes = 32;
  static constexpr int64_t kDefaultWindowNs = 2'000'000'000;

  /// `session` is the session this end serves (it is part of every tag).
  /// Throws std::runtime_error if OpenSSL cannot set up HMAC-SHA256.
  HmacToolAuthenticator(const SessionKey& key, std::string session,
                        int64_t window_ns = kDefaultWindowNs);
  ~HmacToolAuthenticator() override;
  HmacToolAuthenticator(const HmacToolAuthenticator&) = delete;
  HmacToolAuthenticator& operator=(const HmacToolAuthenticator&) = delete;

  /// Sets `epoch`, `wall_ns` (CLOCK_REALTIME now) and `hmac`. The sequence
  /// must rise; if it does not (a new link on the same authenticator) a new,
  /// larger epoch starts so the receiver still accepts the stream.
  void Sign(v1::ToolState* msg) noexcept override;
  /// Checks the tag, then freshness (`EpochGate`); only a message with a
  /// valid tag can advance the replay state.
  [[nodiscard]] AuthVerdict Verify(const v1::ToolState& msg) noexcept override;

  /// Verification against explicit receiver clocks (tests): CLOCK_REALTIME
  /// for the window, CLOCK_MONOTONIC for the quiet period (defaults to the
  /// realtime value).
  [[nodiscard]] AuthVerdict VerifyAt(const v1::ToolState& msg, int64_t now_wall_ns,
                                     std::optional<int64_t> now_mono_ns = std::nullopt) noexcept;
  /// Signing with an explicit sender clock (tests, and the forging tool's
  /// "old but correctly signed" messages).
  void SignAt(v1::ToolState* msg, int64_t now_wall_ns) noexcept;

  [[nodiscard]] uint64_t epoch() const { return epoch_; }

 private:
  /// Computes the tag of `msg` as if in `session_`; false if OpenSSL failed.
  bool Tag(const v1::ToolState& msg, HmacSha256::Tag* tag) noexcept;

  std::string session_;
  HmacSha256 mac_;
  // Signing state.
  uint64_t epoch_ = 0;
  uint64_t last_signed_seq_ = 0;
  // Verification state.
  EpochGate gate_;
};

}  // namespace cutsim::transport

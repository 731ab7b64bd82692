#pragma once
/// @file
/// The debrief's control channel over DDS (topic `cutsim_control`, KIND_CONTROL):
/// the browser bridge writes the instructor's commands, the server playing
/// the recording reads them. Each message is one line of the control
/// language (common/debrief/debrief_command.h), at most 64 bytes.
///
/// With the session key every message is signed like the observer stream
/// (stream_auth.h: HMAC trailer, sender epoch, rising sequence, 2 s window),
/// so only a bridge holding the key steers the session and a captured
/// command cannot be played again. Without a key the session is open: any
/// process on the DDS domain may send commands (the server says so at start).

#include <cstdint>
#include <functional>
#include <memory>
#include <optional>
#include <string>
#include <string_view>

#include "common/transport/codec.h"
#include "common/transport/dds.h"
#include "common/transport/stream_auth.h"
#include "cutsim/v1/wire.pb.h"

namespace cutsim::transport {

/// Writes commands to one session's server.
class DebriefControlWriter {
 public:
  /// Throws InputError (field "--session") on an invalid session name.
  DebriefControlWriter(DdsParticipant& participant, std::string session, std::optional<SessionKey> key);
  /// Sends one command line; false when DDS refused it. Never throws.
  bool Send(std::string_view command);
  /// Servers reading now.
  [[nodiscard]] uint32_t matched_readers() const { return writer_.matched_readers(); }

 private:
  std::string session_;
  DdsTopic topic_;
  DdsWriter writer_;
  std::unique_ptr<PayloadAuthenticator> signer_;
  uint64_t seq_ = 0;
  uint64_t epoch_ = 0;
  v1::DebriefControl msg_;
  Encoder encoder_;
};

/// Counters of a reader.
struct DebriefControlStats {
  uint64_t accepted = 0;
  uint64_t unsigned_samples = 0;  ///< No trailer in a keyed session.
  uint64_t forged = 0;            ///< Wrong tag.
  uint64_t stale = 0;             ///< Replayed, outside the window, or from another sender.
  uint64_t malformed = 0;         ///< Not a DebriefControl, or a command over 64 bytes.
};

/// Reads one session's commands (the server's end).
class DebriefControlReader {
 public:
  DebriefControlReader(DdsParticipant& participant, std::string session, std::optional<SessionKey> key);
  /// Takes every command waiting (waits up to `timeout` for the first) and
  /// calls `fn(line)` for each authentic, fresh one. Returns how many.
  size_t Poll(std::chrono::nanoseconds timeout, const std::function<void(const std::string&)>& fn);
  [[nodiscard]] const DebriefControlStats& stats() const { return stats_; }
  [[nodiscard]] uint32_t matched_writers() const { return reader_.matched_writers(); }

 private:
  std::string session_;
  DdsTopic topic_;
  DdsReader reader_;
  std::unique_ptr<PayloadAuthenticator> verifier_;
  EpochGate gate_;
  v1::DebriefControl msg_;
  DebriefControlStats stats_;
};

}  // namespace cutsim::transport

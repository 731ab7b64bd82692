#pragma once
/// @file
/// The sessions running on a DDS domain, found from their streams: every
/// server publishes its `SessionStatus` once a second on the status topic
/// while a status reader is matched, and one reader of every session
/// (`DdsReader(topic, AnySession)`) hears them all. Nothing is configured by
/// hand; a lab bridge lists what it hears.
///
/// A session is live while its statuses keep coming (within `live_window`),
/// then stopped (its last status is kept, so the list says what it was when
/// it stopped) until `forget_after` has passed. At most `max_sessions` are
/// held: statuses of further sessions are counted and dropped, so a flood of
/// invented session names cannot grow the directory without bound.
///
/// With the lab's session key, only statuses signed with it count (checked
/// on the raw payload before parsing, stream_auth.h); without one the list
/// is unauthenticated: anyone on the domain can announce a session.

#include <chrono>
#include <cstdint>
#include <map>
#include <memory>
#include <optional>
#include <span>
#include <string>
#include <string_view>
#include <vector>

#include "common/transport/dds.h"
#include "common/transport/stream_auth.h"
#include "cutsim/v1/wire.pb.h"

namespace cutsim::transport {

/// The directory's settings.
struct SessionDirectoryOptions {
  std::chrono::milliseconds live_window{3000};   ///< A session silent this long is stopped.
  std::chrono::milliseconds forget_after{600000};///< A stopped session leaves the list after this.
  size_t max_sessions = 256;                     ///< Sessions held at once.
  std::optional<SessionKey> key;                 ///< Only statuses signed with it count; unset: open.
};

/// One session as the directory knows it.
struct SessionEntry {
  std::string session;
  v1::SessionStatus status;       ///< The newest status heard.
  int64_t first_heard_ns = 0;     ///< Monotonic ns of its first status.
  int64_t last_heard_ns = 0;      ///< Monotonic ns of its newest status.
  uint64_t statuses = 0;          ///< Statuses taken.
  bool live = false;              ///< Heard within the live window (as of `Entries`).
  /// Tool messages reached the server between its last two statuses: a
  /// station (the trainee's hand) is connected.
  bool trainee_connected = false;
  /// Frame overruns between its last two statuses, per second of its clock.
  double overruns_per_s = 0;
};

/// Counters of the directory.
struct SessionDirectoryStats {
  uint64_t statuses = 0;     ///< Statuses taken.
  uint64_t malformed = 0;    ///< Statuses that failed to decode, or whose session disagrees with the key.
  uint64_t unsigned_samples = 0;  ///< Without a tag while a key is set.
  uint64_t forged = 0;       ///< Tag did not verify.
  uint64_t stale = 0;        ///< Older than one already taken of the same server (reordered, replayed).
  uint64_t refused_full = 0; ///< Statuses of new sessions while `max_sessions` are held.
  uint64_t forgotten = 0;    ///< Stopped sessions removed after `forget_after`.
};

/// Listens to every session's status (see the file comment). Not
/// thread-safe: one thread polls and reads.
class SessionDirectory {
 public:
  /// Opens the status reader on `participant`'s domain.
  explicit SessionDirectory(DdsParticipant& participant, SessionDirectoryOptions options = {});
  /// A directory fed only through `Process` (tests, fuzzing).
  explicit SessionDirectory(SessionDirectoryOptions options);
  ~SessionDirectory();
  SessionDirectory(const SessionDirectory&) = delete;
  SessionDirectory& operator=(const SessionDirectory&) = delete;

  /// Waits up to `timeout` for statuses and takes every one available;
  /// returns how many were taken. Never throws for sample contents.
  size_t Poll(std::chrono::nanoseconds timeout);
  /// Takes one status payload of `session` as if heard at monotonic `now_ns`;
  /// false when it is dropped (counted in the stats).
  bool Process(std::string_view session, std::span<const uint8_t> payload, int64_t now_ns);

  /// Every session held, by name, with `live` as of `now_ns`; stopped
  /// sessions older than `forget_after` are removed first.
  [[nodiscard]] std::vector<SessionEntry> Entries(int64_t now_ns);
  [[nodiscard]] const SessionDirectoryStats& stats() const { return stats_; }
  [[nodiscard]] bool authenticated() const { return options_.key.has_value(); }

 private:
  struct Held {
    SessionEntry entry;
    std::unique_ptr<PayloadAuthenticator> verifier;  // null in an open directory
  };

  SessionDirectoryOptions options_;
  std::unique_ptr<DdsTopic> topic_;
  std::unique_ptr<DdsReader> reader_;
  std::map<std::string, Held, std::less<>> sessions_;
  v1::SessionStatus msg_;
  SessionDirectoryStats stats_;
};

}  // namespace cutsim::transport

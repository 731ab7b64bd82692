#pragma once
/// @file
/// One server per session: servers announce themselves on
/// `CUTSIM_<session>_SERVER` (LCM) so that a second server started on a
/// session that is already served finds the first and refuses to run, and
/// both say so.
///
/// * Before it loads anything, a server `Claim`s the session: it sends a
///   probe and listens for `probe_ms`. A running server answers a probe at
///   once with its own announcement and logs that a second server tried to
///   join; the prober then refuses (exit status 6 in `cutsim-server`),
///   naming the host and process that serve the session.
/// * While it runs (`Start`), a server announces itself every `period_ms`
///   from a thread of its own. Two servers that started within the probe
///   time of each other find each other there: the one with the newer epoch
///   (the later start) is refused (`refused()` turns true and a stop is
///   requested) and the older one logs the conflict.
/// * With a session key, announcements are signed (stream_auth.h) and only
///   authentic ones signed within `window_ns` of our clock count, so no one
///   without the key can keep a server from starting, and an old
///   announcement played back cannot either. Without a key (an open
///   session) anyone on the network can. Messages that fail the check are
///   counted (`unauthenticated`); the first one is also logged.
///
/// The presence uses an LCM instance of its own, so it shares nothing with
/// the haptic link's threads.

#include <atomic>
#include <cstdint>
#include <memory>
#include <mutex>
#include <optional>
#include <span>
#include <string>
#include <thread>

#include "common/transport/stream_auth.h"

namespace cutsim::transport {

class LcmBus;
class LcmSubscription;

/// Exit status of a server that refuses to serve a session twice.
inline constexpr int kExitDuplicateServer = 6;

struct ServerPresenceOptions {
  std::string lcm_url;                 ///< The session's LCM URL.
  std::string session;                 ///< Validated by the caller.
  std::optional<SessionKey> key;       ///< Sign and require signatures; unset: open.
  int probe_ms = 300;                  ///< How long `Claim` listens.
  int period_ms = 1000;                ///< Announcement period while running.
  int64_t window_ns = EpochGate::kDefaultWindowNs;  ///< Accepted |clock difference|.
};

/// Another server of the same session.
struct PeerServer {
  uint64_t epoch = 0;  ///< Its start, CLOCK_REALTIME ns.
  std::string host;
  uint32_t pid = 0;
  /// "cutsim-server pid P on host H, started YYYY-MM-DD HH:MM:SS UTC".
  [[nodiscard]] std::string Describe() const;
};

struct ServerPresenceStats {
  uint64_t announced = 0;        ///< Announcements and probes sent.
  uint64_t peers = 0;            ///< Authentic messages of other servers of the session.
  uint64_t unauthenticated = 0;  ///< Unsigned, forged, stale or malformed messages, ignored.
  uint64_t probes_answered = 0;  ///< Second servers told that this one serves the session.
};

/// The presence of one server (see the file comment). `Claim` and `Start`
/// on one thread; `refused`, `refused_by` and `stats` from any.
class ServerPresence {
 public:
  /// Opens its own LCM instance at `options.lcm_url`. Throws `InputError`
  /// naming `--lcm-url` when LCM cannot open it.
  explicit ServerPresence(ServerPresenceOptions options);
  ~ServerPresence();  ///< Stops the announcing thread.
  ServerPresence(const ServerPresence&) = delete;
  ServerPresence& operator=(const ServerPresence&) = delete;

  /// Probes the session for `probe_ms`; the server already serving it, if
  /// any (this server must then not run).
  [[nodiscard]] std::optional<PeerServer> Claim();
  /// Announces this server every `period_ms` and answers probes, on a
  /// thread of its own, until destroyed.
  void Start();

  /// True when an older server of the session was found after `Start`; a
  /// stop has then been requested (`RequestStop`).
  [[nodiscard]] bool refused() const { return refused_.load(std::memory_order_acquire); }
  [[nodiscard]] std::optional<PeerServer> refused_by() const;
  [[nodiscard]] ServerPresenceStats stats() const;
  [[nodiscard]] uint64_t epoch() const { return epoch_; }

 private:
  void Announce(bool probe);
  void OnMessage(std::span<const uint8_t> bytes);
  void Run();

  ServerPresenceOptions options_;
  uint64_t epoch_;
  uint64_t seq_ = 0;
  std::string host_;
  uint32_t pid_;
  std::unique_ptr<PayloadAuthenticator> auth_;
  std::unique_ptr<LcmBus> bus_;
  std::unique_ptr<LcmSubscription> subscription_;
  bool running_phase_ = false;  // owned by whichever thread handles the bus
  int64_t last_conflict_log_ns_ = 0;
  std::atomic<bool> stop_{false};
  std::atomic<bool> refused_{false};
  mutable std::mutex mutex_;  // guards refused_by_ and stats_
  std::optional<PeerServer> refused_by_;
  ServerPresenceStats stats_;
  std::thread thread_;
};

}  // namespace cutsim::transport

#pragma once
/// @file
/// The lab view's bridge: one process that finds every session running on
/// its DDS domain (transport::SessionDirectory, from the servers' status
/// stream), reads each live session's mesh stream once, and serves the lab
/// page (`web/lab`) and each session's observer page to browsers from one
/// ObserverServer with a channel per session:
///  - `/ws` (channel ""): the lab list as JSON, twice a second (LabListJson);
///  - `/ws?session=NAME`: session NAME's frames, exactly what a single
///    session's bridge (`cutsim-viewer --serve`) sends, so the observer page
///    and the lab's grid views decode them alike.
/// However many browsers watch a session, the bridge holds one DDS reader of
/// it; a session the list no longer holds loses its reader and its channel.

#include <chrono>
#include <cstdint>
#include <filesystem>
#include <map>
#include <memory>
#include <optional>
#include <string>
#include <vector>

#include "common/transport/dds.h"
#include "common/transport/mesh_subscriber.h"
#include "common/transport/session_directory.h"
#include "common/web/browser_bridge.h"
#include "common/web/observer_server.h"

namespace cutsim::web {

/// The lab page's files (web/lab) and the observer page's (web/observer,
/// whose index is served as /observer.html), by URL path.
[[nodiscard]] std::map<std::string, std::filesystem::path> LabPageFiles(const std::filesystem::path& lab_root,
                                                                       const std::filesystem::path& observer_root);

/// What the lab list says of one session beyond its status.
struct LabSessionView {
  transport::SessionEntry entry;
  bool watched = false;        ///< The bridge reads its mesh stream.
  bool current = false;        ///< Its replica is current (frames flow).
  double frame_age_ms = -1;    ///< Since its newest mesh sample; −1: none yet.
  double frames_per_s = 0;     ///< Frames relayed to browsers, over the last ~2 s.
  uint64_t bridge_gaps = 0;    ///< Sequence gaps of its stream at the bridge.
  uint64_t resyncs = 0;        ///< Times its replica lost sync.
  std::optional<v1::SessionMetrics> metrics;  ///< As of its newest frame.
};

/// One finished session of a trainee, for the list's trend (SI units).
struct TrendPoint {
  int64_t finished_unix_s = 0;
  double duration = 0;        ///< s
  double mean_deviation = 0;  ///< m
  double depth_error = 0;     ///< m
  double peak_force = 0;      ///< N
};

/// Each trainee's latest finished sessions, oldest first (the lab's score
/// history, read by the app).
using Trends = std::map<std::string, std::vector<TrendPoint>>;

/// The lab list as one JSON text: {"type":"lab","authenticated":…,
/// "sessions":[{…}, …]}. Strings are escaped and limited to printable ASCII
/// (anything else becomes '?'); non-finite numbers are null.
/// With `trends`, each session whose trainee has finished sessions carries
/// them as "trend": [{finished, duration, mean_deviation, depth_error,
/// peak_force}, …].
[[nodiscard]] std::string LabListJson(const std::vector<LabSessionView>& sessions, bool authenticated,
                                      const Trends& trends = {});

/// The bridge's settings.
struct LabBridgeOptions {
  ObserverServerOptions server;                  ///< `channels` is set by the bridge.
  transport::SessionDirectoryOptions directory;  ///< Its key also verifies the mesh streams.
  size_t max_watched = 64;                       ///< Sessions whose mesh streams are read at once.
  std::chrono::milliseconds list_period{500};    ///< How often the list goes out.
};

/// Counters of the bridge.
struct LabBridgeStats {
  size_t sessions = 0;          ///< Sessions listed (live and stopped).
  size_t live = 0;              ///< Of them, live.
  size_t watched = 0;           ///< Mesh streams read now.
  uint64_t frames_relayed = 0;  ///< Frames sent out, all sessions.
  uint64_t lists_sent = 0;      ///< Lab lists broadcast.
  uint64_t refused_watch = 0;   ///< Live sessions left unwatched at the `max_watched` cap (list polls).
};

/// The lab bridge (see the file comment). One thread calls `Poll`.
class LabBridge {
 public:
  /// Starts the server and the directory's reader. Throws as ObserverServer does.
  LabBridge(transport::DdsParticipant& participant, LabBridgeOptions options);
  ~LabBridge();
  LabBridge(const LabBridge&) = delete;
  LabBridge& operator=(const LabBridge&) = delete;

  /// Polls every session's stream and relays new frames, then waits up to
  /// `timeout` for statuses; sends the list when its period is due.
  void Poll(std::chrono::nanoseconds timeout);

  [[nodiscard]] const ObserverServer& server() const { return *server_; }
  [[nodiscard]] const LabBridgeStats& stats() const { return stats_; }
  /// The list as the page last received it (or would now).
  [[nodiscard]] std::vector<LabSessionView> Views();
  /// The trainees' trends the list carries from now on.
  void SetTrends(Trends trends) { trends_ = std::move(trends); }

 private:
  struct Watched;
  void UpdateWatched(const std::vector<transport::SessionEntry>& entries);
  void SendList();

  transport::DdsParticipant& participant_;
  LabBridgeOptions options_;
  std::unique_ptr<ObserverServer> server_;
  transport::SessionDirectory directory_;
  std::map<std::string, std::unique_ptr<Watched>> watched_;
  Trends trends_;
  int64_t next_list_ns_ = 0;
  LabBridgeStats stats_;
};

}  // namespace cutsim::web

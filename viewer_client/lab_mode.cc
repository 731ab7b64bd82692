// cutsim-viewer --lab: the lab bridge's loop. Thin: the bridge is
// common/web/lab_bridge.h.
#include <cstdio>
#include <filesystem>
#include <tuple>
#include <vector>

#include <fmt/format.h>

#include "common/core/clock.h"
#include "common/core/log.h"
#include "common/record/score_history.h"
#include "common/transport/dds.h"
#include "common/transport/stream_auth.h"
#include "common/web/lab_bridge.h"
#include "viewer_client/viewer_app.h"

namespace cutsim::viewer {
namespace {

/// Sessions of each trainee the list shows, at most.
constexpr size_t kTrendSessions = 20;

/// The listed trainees' latest finished sessions from the lab's history.
/// A history that cannot be read (missing, locked, corrupt, another
/// version) is logged once per distinct error and leaves the trends empty:
/// the lab page goes on without them.
web::Trends ReadTrends(const std::string& path, const std::vector<web::LabSessionView>& views,
                       std::string* last_error) {
  web::Trends trends;
  std::error_code ec;
  if (!std::filesystem::exists(path, ec)) return trends;  // no session has finished yet; never created here
  try {
    const record::ScoreHistory history = record::ScoreHistory::Open(path);
    for (const web::LabSessionView& v : views) {
      const std::string& trainee = v.entry.status.trainee();
      if (trainee.empty() || !record::CheckTraineeName(trainee).empty() || trends.contains(trainee)) continue;
      const std::vector<record::SessionEntry> entries = history.ForTrainee(trainee);
      std::vector<web::TrendPoint>& points = trends[trainee];
      const size_t first = entries.size() > kTrendSessions ? entries.size() - kTrendSessions : 0;
      for (size_t i = first; i < entries.size(); ++i) {
        const record::SessionEntry& e = entries[i];
        points.push_back({.finished_unix_s = e.finished_unix_s, .duration = e.duration,
                          .mean_deviation = e.mean_deviation, .depth_error = e.depth_error,
                          .peak_force = e.peak_force});
      }
    }
    last_error->clear();
  } catch (const std::exception& e) {
    if (*last_error != e.what()) Log().warn("lab: no trends: {}", e.what());
    *last_error = e.what();
  }
  return trends;
}

}  // namespace

int RunLab(const ViewerOptions& o, const volatile int& stop) {
  const int64_t start_ns = MonotonicNs();
  const std::string config = o.dds_config.empty() ? std::string()
                                                  : "file://" + std::filesystem::absolute(o.dds_config).string();
  transport::DdsParticipant participant(o.dds_domain, config);
  web::LabBridgeOptions lo;
  std::tie(lo.server.address, lo.server.port) = web::ParseHostPort(o.lab, "--lab");
  if (!o.token_file.empty()) lo.server.token = web::LoadObserverToken(o.token_file);
  lo.server.host_names = o.host_names;
  lo.server.files = web::LabPageFiles(o.lab_root, o.web_root);
  // An instructor's page holds up to 8 grid views and the list, and a few
  // observer pages besides.
  lo.server.max_clients = 128;
  lo.directory.key = transport::LoadSessionKey(o.key_file);
  if (lo.directory.key) {
    Log().info("lab: only sessions signed with the session key are listed");
  } else {
    Log().warn("lab: no session key (--key-file or ${}): the sessions listed are not authenticated",
               transport::kSessionKeyEnv);
  }
  web::LabBridge bridge(participant, std::move(lo));
  // On stdout, for scripts: the address a browser opens.
  std::printf("lab: %s\n", bridge.server().Url().c_str());
  std::fflush(stdout);
  Log().info("lab: listing every session on DDS domain {}", o.dds_domain);
  const char* reason = "signal";
  int64_t next_trends_ns = 0;
  std::string history_error;
  while (stop == 0) {
    if (!o.history.empty() && MonotonicNs() >= next_trends_ns) {
      // Sessions finish rarely: the history is read every 10 s.
      next_trends_ns = MonotonicNs() + 10'000'000'000;
      bridge.SetTrends(ReadTrends(o.history, bridge.Views(), &history_error));
    }
    if (o.duration && MonotonicNs() - start_ns >= static_cast<int64_t>(*o.duration * 1e9)) {
      reason = "duration";
      break;
    }
    // Streams are polled without waiting; the wait is on the statuses, so
    // the loop turns at least every 5 ms and frames leave within that.
    bridge.Poll(std::chrono::milliseconds(5));
  }
  const web::LabBridgeStats& s = bridge.stats();
  const web::ObserverServerStats b = bridge.server().stats();
  std::fprintf(stderr,
               "cutsim-viewer: lab summary: {\"sessions\":%zu,\"live\":%zu,\"watched\":%zu,\"frames_relayed\":%llu,"
               "\"lists_sent\":%llu,\"browsers_accepted\":%llu,\"browser_bytes_sent\":%llu,\"exit_reason\":\"%s\"}\n",
               s.sessions, s.live, s.watched, static_cast<unsigned long long>(s.frames_relayed),
               static_cast<unsigned long long>(s.lists_sent), static_cast<unsigned long long>(b.accepted),
               static_cast<unsigned long long>(b.bytes_sent), reason);
  return 0;
}

}  // namespace cutsim::viewer

// cutsim-viewer --lab: the lab bridge's loop. Thin: the bridge is
// common/web/lab_bridge.h.
#include <cstdio>
#include <filesystem>
#include <tuple>

#include <fmt/format.h>

#include "common/core/clock.h"
#include "common/core/log.h"
#include "common/transport/dds.h"
#include "common/transport/stream_auth.h"
#include "common/web/lab_bridge.h"
#include "viewer_client/viewer_app.h"

namespace cutsim::viewer {

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
  while (stop == 0) {
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

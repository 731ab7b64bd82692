#pragma once
/// @file
/// The trainee page's 3-D view: relays the session's mesh stream (the DDS
/// stream the observers read) to the trainee's WebSocket, encoded as for
/// the observer pages (common/web/browser_frames.h), so the page draws the
/// tissue it cuts. One DDS reader on a thread of its own: it polls the
/// stream, encodes each new frame once and queues it on the trainee server,
/// which only ever holds the newest frames for a slow page. The servo loop
/// never waits on it.

#include <atomic>
#include <cstdint>
#include <memory>
#include <optional>
#include <string>
#include <thread>

#include "common/transport/stream_auth.h"

namespace cutsim::web {
class TraineeServer;
}

namespace cutsim::haptic_client {

/// Where the mesh stream is read.
struct TraineeViewOptions {
  std::string session = "default";
  uint32_t dds_domain = 0;
  std::string dds_config;  ///< Cyclone configuration file; empty = $CYCLONEDDS_URI or the default.
  std::optional<transport::SessionKey> key;  ///< Only frames signed with it are shown; none = an open session.
};

class TraineeView {
 public:
  /// Starts reading (throws InputError naming --session, --dds-domain or
  /// --dds-config). `server` must outlive the view.
  TraineeView(web::TraineeServer& server, TraineeViewOptions options);
  ~TraineeView();
  TraineeView(const TraineeView&) = delete;
  TraineeView& operator=(const TraineeView&) = delete;

  /// Mesh frames queued for the page so far.
  [[nodiscard]] uint64_t frames() const { return frames_.load(std::memory_order_relaxed); }

 private:
  struct Reader;
  void Run();

  web::TraineeServer& server_;
  std::unique_ptr<Reader> reader_;
  std::atomic<bool> stop_{false};
  std::atomic<uint64_t> frames_{0};
  std::thread thread_;
};

}  // namespace cutsim::haptic_client

#include "haptic_client/trainee_view.h"

#include <chrono>
#include <filesystem>

#include "common/transport/dds.h"
#include "common/transport/mesh_subscriber.h"
#include "common/web/browser_frames.h"
#include "common/web/trainee_server.h"

namespace cutsim::haptic_client {

struct TraineeView::Reader {
  explicit Reader(const TraineeViewOptions& o)
      : participant(o.dds_domain,
                    o.dds_config.empty() ? std::string() : "file://" + std::filesystem::absolute(o.dds_config).string()),
        subscriber(participant, o.session, o.key) {}
  transport::DdsParticipant participant;
  transport::MeshStreamSubscriber subscriber;
  web::BrowserFrameEncoder encoder;
  uint64_t last_version = 0;
};

TraineeView::TraineeView(web::TraineeServer& server, TraineeViewOptions options)
    : server_(server), reader_(std::make_unique<Reader>(options)) {
  thread_ = std::thread([this] { Run(); });
}

TraineeView::~TraineeView() {
  stop_ = true;
  if (thread_.joinable()) thread_.join();
}

void TraineeView::Run() {
  Reader& r = *reader_;
  while (!stop_.load()) {
    r.subscriber.Poll(std::chrono::milliseconds(50));
    if (r.subscriber.state_version() == r.last_version || !r.subscriber.current()) continue;
    r.last_version = r.subscriber.state_version();
    auto frame = r.encoder.Frame(r.subscriber.replica());
    const bool snapshot = !frame->empty() && static_cast<uint8_t>((*frame)[0]) == web::kSurfaceSnapshot;
    server_.SendMesh(std::move(frame), snapshot);
    frames_.fetch_add(1, std::memory_order_relaxed);
  }
}

}  // namespace cutsim::haptic_client

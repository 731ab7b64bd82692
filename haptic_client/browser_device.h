#pragma once
/// @file
/// The `browser` device: a trainee page (web/trainee) drives the scalpel with
/// mouse, trackpad and keyboard over a WebSocket (common/web/trainee_server.h)
/// served by the haptic station itself.
///
/// * Samples: the page sends one text message per input event,
///   `p T U V W DX DY DZ B`: T the event's page time (ms, finite, ≥ 0, not
///   going back), U V W the tip in the workspace box normalised to [0, 1]
///   (U → x, V → y, W → z), DX DY DZ the blade direction (tip → handle, norm
///   within 10 % of 1, renormalised), B the buttons (0..3: bit 0 cutting,
///   bit 1 clutch). A sample's time must also lie within kClockWindowMs of
///   the stream's clock (the page time mapped to CLOCK_MONOTONIC, below) at
///   its arrival: a sample far in the future or the past is refused, so one
///   wild time cannot hold the tool. When every sample is refused for its
///   time for kReanchorMs, the page's clock is taken to have restarted and
///   the stream's clock is set again from the next sample.
/// * Heartbeat: `h` says the page is there while the trainee does not move
///   (the server frees a seat that hears nothing; trainee_server.h).
///   Anything else is refused and counted by reason.
/// * Smoothing: the loop renders the pose at `now − delay`, interpolating
///   linearly between the two newest samples (the blade direction
///   renormalised), where `delay` is the mean input period (clamped to
///   [4, 50] ms) and the page's clock is mapped to CLOCK_MONOTONIC by the
///   smallest receive − send offset seen since the page connected. Before
///   the older sample the pose holds it; past the newer one it holds that
///   one (the trainee stopped moving).
/// * Threads: the server's I/O thread parses and publishes the newest
///   sample pair through a wait-free triple buffer (transport::Mailbox); the
///   1 kHz loop takes it and interpolates without allocating or locking, and
///   publishes its force and the model's cut state through another mailbox.
///   The I/O thread looks at that mailbox at 500 Hz and sends a frame as
///   soon as it answers a new sample, and at least at 60 Hz, so an input
///   waits for the next poll (≤ 2 ms), not for the next 60 Hz tick.
/// * A page that leaves releases the buttons (cutting off); the tool holds
///   its pose until a page connects again.

#include <array>
#include <filesystem>
#include <map>
#include <optional>
#include <vector>
#include <cstdint>
#include <memory>
#include <mutex>
#include <string>
#include <string_view>
#include <utility>

#include <Eigen/Core>

#include "common/transport/mailbox.h"
#include "haptic_client/device.h"
#include "haptic_client/trainee_view.h"

namespace cutsim::transport {
struct SessionKey;
}
namespace cutsim::web {
class TraineeServer;
}

namespace cutsim::haptic_client {

/// One input sample, mapped to the workspace.
struct BrowserSample {
  double page_ms = 0.0;  ///< The page's event time, ms.
  ToolPose pose;         ///< In the device's workspace, m.
  uint32_t buttons = 0;
};

/// Why a message was refused.
enum class SampleError { kNone, kFormat, kNotFinite, kRange, kDirection, kButtons, kTimeBackwards, kClock, kCount };

/// How far a sample's time may lie from the stream's clock, ms.
inline constexpr double kClockWindowMs = 1000.0;
/// How long samples refused for their time make the stream's clock restart, ms.
inline constexpr double kReanchorMs = 1000.0;

/// Parses and validates one page message against the workspace box;
/// `previous_ms` is the last accepted sample's page time (−1: none).
SampleError ParseBrowserSample(std::string_view text, const DeviceInfo& info, double previous_ms,
                               BrowserSample* out) noexcept;

/// The two newest samples and the mapping of page time to CLOCK_MONOTONIC.
struct SamplePair {
  BrowserSample older;
  BrowserSample newer;
  int count = 0;              ///< Samples held: 0, 1 or 2.
  int64_t offset_ns = 0;      ///< monotonic = page time + offset.
  int64_t delay_ns = 16'000'000;  ///< Render delay (≈ one input period).
};

/// The pose at `now_ns` from a sample pair (see the file comment). `used_ms`
/// is the page time of the newest sample with a non-zero weight in it.
void InterpolatePose(const SamplePair& pair, int64_t now_ns, DeviceState* state, double* used_ms) noexcept;

/// What the page's messages say, in order: validates each against the
/// workspace and the stream's clock, and keeps the newest sample pair with
/// the mapping of page time to CLOCK_MONOTONIC (see the file comment). Not
/// thread-safe; the server's I/O thread owns it.
class SampleStream {
 public:
  explicit SampleStream(DeviceInfo info) : info_(std::move(info)) {}
  /// One message (a sample or a heartbeat) read at `receive_ns`. kNone when
  /// it was taken (`*heartbeat` tells a heartbeat), else why it was refused.
  SampleError Push(std::string_view text, int64_t receive_ns, bool* heartbeat, bool* reanchored) noexcept;
  /// A new page: its clock is unknown.
  void Restart() noexcept;
  /// The page left: hold the newest pose with the buttons released.
  void Release() noexcept;
  [[nodiscard]] const SamplePair& pair() const { return pair_; }

 private:
  DeviceInfo info_;
  SamplePair pair_;
  double interval_ms_ = 16.0;
  int64_t time_refused_since_ns_ = -1;  // first of a run of samples refused for their time
};

/// The page's WebSocket token: hex HMAC-SHA256 of a fixed label under the
/// session key (the key itself never leaves the station).
std::string TraineeToken(const transport::SessionKey& key);

/// Counters of the page's messages.
struct BrowserDeviceStats {
  uint64_t samples = 0;  ///< Accepted samples.
  uint64_t heartbeats = 0;  ///< Heartbeats (`h`).
  uint64_t reanchors = 0;   ///< Restarts of the stream's clock.
  std::array<uint64_t, static_cast<size_t>(SampleError::kCount)> refused{};  ///< By SampleError.
  uint64_t connections = 0;
  [[nodiscard]] uint64_t refused_total() const;
};

/// The frame the loop hands the page: force, cut state, the sample used.
struct BrowserFrame {
  Eigen::Vector3d force = Eigen::Vector3d::Zero();
  Eigen::Vector3d tip = Eigen::Vector3d::Zero();
  double used_ms = -1.0;
  uint64_t cuts = 0;
  bool contact = false;
  uint32_t buttons = 0;
};

struct BrowserDeviceOptions {
  std::string address = "127.0.0.1";
  uint16_t port = 0;
  std::string token;        ///< TraineeToken of the session key.
  std::string page_dir;     ///< The page's files (web/trainee; web/common beside it).
  std::string three_dir;    ///< three.js's npm package; empty = web/observer/node_modules/three beside page_dir.
  std::string url_file;     ///< If set, the page's URL (with the token) is written here, mode 0600.
  std::vector<std::string> host_names;  ///< Further names the page may be opened at (--host-name).
  /// What the page draws beside the device: world = scale · device + offset
  /// (the station's workspace mapping), the blade's length, and the scene's
  /// planned incision (m, world; empty: none).
  double world_scale = 1.0;
  Eigen::Vector3d world_offset = Eigen::Vector3d::Zero();
  double blade_length = 0.02;
  std::vector<Eigen::Vector3d> planned_incision;
  /// The session's mesh stream for the page's 3-D view; none: no tissue drawn.
  std::optional<TraineeViewOptions> view;
};

/// The trainee page's files by URL path (see BrowserDeviceOptions).
[[nodiscard]] std::map<std::string, std::filesystem::path> TraineePageFiles(const std::string& page_dir,
                                                                            const std::string& three_dir);

class BrowserDevice final : public HapticDevice {
 public:
  /// The device's info (workspace box, no force limit beyond the renderer's).
  static DeviceInfo DefaultInfo();

  /// Starts the server (throws InputError naming --serve or the page file).
  BrowserDevice(const BrowserDeviceOptions& options, DeviceInfo info);
  ~BrowserDevice() override;

  [[nodiscard]] const DeviceInfo& info() const override { return info_; }
  void Start(int64_t start_ns) override;
  void Read(int64_t now_ns, DeviceState* state) noexcept override;
  void SetForce(const Eigen::Vector3d& force) noexcept override;
  void ShowModel(uint64_t cuts, bool contact) noexcept override;
  void Stop() noexcept override;

  /// The page's URL with the token.
  [[nodiscard]] std::string url() const;
  /// Message counters (a consistent copy; thread-safe).
  [[nodiscard]] BrowserDeviceStats stats() const;
  [[nodiscard]] const web::TraineeServer& server() const { return *server_; }

  /// I/O-thread side, public for the tests: a page message, a connection.
  void OnMessage(std::string_view text, int64_t receive_ns) noexcept;
  std::string OnOpen();
  void OnClose() noexcept;
  std::string MakeFrame();
  /// Whether the newest frame answers a sample the page has no frame for.
  bool FrameIsUrgent() noexcept;

 private:
  DeviceInfo info_;
  std::string url_;
  // I/O thread.
  SampleStream stream_;
  mutable std::mutex stats_mu_;  // the I/O thread's counters, read by stats()
  BrowserDeviceStats stats_;
  BrowserFrame io_frame_;
  double sent_used_ms_ = -1.0;  // used_ms of the last frame sent
  // Between the threads.
  transport::Mailbox<SamplePair> samples_;
  transport::Mailbox<BrowserFrame> frames_;
  // Loop thread.
  SamplePair loop_pair_;
  BrowserFrame loop_frame_;
  std::string hello_;
  std::unique_ptr<web::TraineeServer> server_;
  std::unique_ptr<TraineeView> view_;  // last: stops before the server it feeds
};

}  // namespace cutsim::haptic_client

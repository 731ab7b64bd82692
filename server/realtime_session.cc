// The real-time session: physics paced to the wall clock, tool poses in and
// local models out over LCM (seed §3.4's buffer model), mesh frames out to
// any number of viewers over DDS. Thin glue: the work is in common/.
#include <time.h>

#include <algorithm>
#include <cmath>
#include <csignal>
#include <cstdio>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <memory>
#include <optional>
#include <vector>

#include <fmt/format.h>

#include "common/core/clock.h"
#include "common/core/error.h"
#include "common/core/log.h"
#include "common/haptics/local_model.h"
#include "common/sim/checkpoint.h"
#include "common/sim/scene_loader.h"
#include "common/sim/simulation.h"
#include "common/transport/channels.h"
#include "common/transport/dds.h"
#include "common/transport/haptic_link.h"
#include "common/transport/lcm_bus.h"
#include "common/transport/mesh_stream.h"
#include "common/transport/realtime_thread.h"
#include "server/recorder.h"
#include "server/server_app.h"

namespace cutsim::server {

extern volatile std::sig_atomic_t g_stop;
extern volatile std::sig_atomic_t g_print_stats;

namespace {

/// CPU time of the calling thread, ns.
int64_t ThreadCpuNs() {
  timespec ts{};
  clock_gettime(CLOCK_THREAD_CPUTIME_ID, &ts);
  return static_cast<int64_t>(ts.tv_sec) * 1'000'000'000 + ts.tv_nsec;
}

/// Frame-time statistics kept in a preallocated ring (no allocation per frame).
class FrameStats {
 public:
  explicit FrameStats(size_t capacity) : samples_(capacity) {}
  void Add(double seconds) {
    samples_[next_ % samples_.size()] = seconds;
    ++next_;
    max_ = std::max(max_, seconds);
  }
  [[nodiscard]] double Percentile(double p) const {
    const size_t n = std::min(next_, samples_.size());
    if (n == 0) return 0.0;
    std::vector<double> sorted(samples_.begin(), samples_.begin() + static_cast<std::ptrdiff_t>(n));
    const size_t k = std::min(n - 1, static_cast<size_t>(p * static_cast<double>(n - 1) + 0.5));
    std::nth_element(sorted.begin(), sorted.begin() + static_cast<std::ptrdiff_t>(k), sorted.end());
    return sorted[k];
  }
  [[nodiscard]] double max() const { return max_; }
  [[nodiscard]] size_t count() const { return next_; }

 private:
  std::vector<double> samples_;
  size_t next_ = 0;
  double max_ = 0.0;
};

struct SessionCounters {
  uint64_t frames = 0;
  uint64_t overruns = 0;
  uint64_t tool_messages = 0;
  uint64_t models_published = 0;
  uint64_t viewer_frames = 0;
};

/// Latencies of the tool pose behind each local model computed from a pose
/// taken in its own frame (one sample per such model).
struct LatencyStats {
  /// Client's device read (ToolSample::stamp_ns) → model published: what the
  /// haptic side measures minus the model's LCM hop. Same CLOCK_MONOTONIC
  /// only on one host; across machines read receive_to_model instead.
  FrameStats pose_to_model{1 << 16};
  FrameStats receive_to_model{1 << 16};  ///< Pose accepted by the server → model published.
};

std::string StatsJson(const ServerOptions& o, const sim::SimulationSummary& s, const SessionCounters& c,
                      const FrameStats& frame_time, const LatencyStats& latency,
                      const transport::HapticServerLinkStats& link, const transport::MeshStreamStats& mesh) {
  return fmt::format(
      "{{\"session\": \"{}\", \"frames\": {}, \"sim_time\": {:.6g}, \"frame_overruns\": {}, "
      "\"frame_time_p50_ms\": {:.4g}, \"frame_time_p99_ms\": {:.4g}, \"frame_time_max_ms\": {:.4g}, "
      "\"pose_to_model_p50_ms\": {:.4g}, \"pose_to_model_p99_ms\": {:.4g}, \"pose_to_model_max_ms\": {:.4g}, "
      "\"receive_to_model_p50_ms\": {:.4g}, \"receive_to_model_p99_ms\": {:.4g}, \"pose_latency_samples\": {}, "
      "\"frames_with_pose\": {}, "
      "\"tool_messages\": {}, \"tool_rejected\": {}, \"models_published\": {}, "
      "\"viewer_frames\": {}, \"viewer_frames_without_reader\": {}, \"snapshots\": {}, \"deltas\": {}, "
      "\"tool_unsigned\": {}, \"tool_forged\": {}, \"tool_replayed\": {}, "
      "\"cuts\": {}, \"topology_version\": {}, \"components\": {}, \"status\": \"{}\"}}",
      o.session, c.frames, s.sim_time, c.overruns, 1e3 * frame_time.Percentile(0.5),
      1e3 * frame_time.Percentile(0.99), 1e3 * frame_time.max(), 1e3 * latency.pose_to_model.Percentile(0.5),
      1e3 * latency.pose_to_model.Percentile(0.99), 1e3 * latency.pose_to_model.max(),
      1e3 * latency.receive_to_model.Percentile(0.5), 1e3 * latency.receive_to_model.Percentile(0.99),
      latency.pose_to_model.count(), c.tool_messages, link.accepted,
      link.foreign_session + link.stale + link.duplicate + link.invalid + link.decode_errors +
          link.unauthenticated,
      c.models_published, mesh.frames, mesh.skipped_no_reader, mesh.snapshots, mesh.deltas,
      link.auth_unsigned, link.auth_forged, link.auth_replayed, s.cuts,
      s.topology_version, s.components, s.status);
}

}  // namespace

int ServerApp::RunRealtime() {
  transport::ValidateSessionName(options_.session, "--session");
  const sim::LoadedScene scene = sim::LoadScene(options_.scene);
  auto simulation = sim::Simulation::Create(
      scene, {.threads = options_.threads, .precision = options_.precision});
  sim::PeriodicCheckpointer checkpointer(options_.checkpoint, options_.checkpoint_every);  // checkpoints
  if (options_.resume) (void)checkpointer.Resume(*simulation);
  const double frame_dt = options_.frame_rate > 0 ? 1.0 / options_.frame_rate : simulation->frame_dt();

  // Access control and recording (issue 7): null when not asked for.
  const auto authenticator = MakeToolAuthenticator(options_);
  // LCM's udpm receive thread starts on the first subscription and inherits
  // this scope's SCHED_FIFO priority (when permitted): poses then reach the
  // link's receive thread while the physics computes.
  // --no-rt: every thread stays at normal priority.
  const int lcm_priority = options_.realtime_priority ? transport::kLcmThreadPriority : 0;
  std::optional<transport::ScopedThreadFifo> lcm_scope;
  if (lcm_priority > 0) lcm_scope.emplace(lcm_priority);
  transport::LcmBus bus(options_.lcm_url);
  transport::HapticServerLink link(bus, options_.session, {.authenticator = authenticator.get()});
  lcm_scope.reset();
  auto recorder = options_.record.empty() ? nullptr
                                          : std::make_unique<SessionRecorder>(
                                                options_.record, options_.session, options_.scene, *simulation);
  std::string dds_config;
  if (!options_.dds_config.empty()) {
    dds_config = "file://" + std::filesystem::absolute(options_.dds_config).string();
  }
  transport::DdsParticipant participant(options_.dds_domain, dds_config);
  transport::MeshStreamPublisher publisher(participant, options_.session);

  // Tool poses are received on their own thread as they arrive; the physics
  // takes the newest right before each step (see the frame order below).
  link.StartReceiving(lcm_priority);
  // The physics thread itself runs SCHED_FIFO below the LCM threads and the
  // haptic loop (realtime_thread.h), set after every helper thread (DDS, LCM)
  // exists so none inherits it.
  const int fifo_error =
      options_.realtime_priority ? transport::SetCurrentThreadFifo(transport::kServerPhysicsPriority) : 0;
  bool physics_fifo = options_.realtime_priority && fifo_error == 0;
  if (options_.realtime_priority && !physics_fifo) {
    Log().warn("SCHED_FIFO priority {} not permitted for the physics thread ({}): it runs as a normal "
               "thread and other load can delay frames and the local model (grant CAP_SYS_NICE or an "
               "rtprio limit)",
               transport::kServerPhysicsPriority, std::strerror(fifo_error));
  }
  // A SCHED_FIFO loop that cannot keep up never sleeps: it would starve the
  // normal threads on its core and run into the kernel's RT throttling at
  // 95% (which would also stall the haptic loop if it shares the core). Once
  // per second the physics' own CPU time (not wall time, which includes
  // preemption) is compared with the wall time: above kMaxFifoBusy the
  // thread goes back to SCHED_OTHER, and below kResumeFifoBusy it returns to
  // SCHED_FIFO.
  constexpr int64_t kFifoWindowNs = 1'000'000'000;
  constexpr double kMaxFifoBusy = 0.9;
  constexpr double kResumeFifoBusy = 0.7;
  const bool fifo_permitted = physics_fifo;
  int64_t window_start_ns = MonotonicNs();
  int64_t window_cpu_start_ns = ThreadCpuNs();

  const auto& hp = scene.scene.haptics();
  Log().info("session '{}': physics {:.0f} Hz, viewers {:.0f} Hz, LCM {}, DDS domain {}",
             options_.session, 1.0 / frame_dt, options_.viewer_fps, options_.lcm_url,
             options_.dds_domain);

  SessionCounters counters;
  FrameStats frame_time(1 << 16);
  LatencyStats latency;
  sim::MeshView view;
  const int64_t frame_ns = static_cast<int64_t>(std::llround(frame_dt * 1e9));
  const int64_t viewer_period_ns = static_cast<int64_t>(std::llround(1e9 / options_.viewer_fps));
  const int64_t client_timeout_ns = static_cast<int64_t>(options_.client_timeout * 1e9);
  const int64_t start_ns = MonotonicNs();
  int64_t deadline = start_ns;
  int64_t next_viewer_ns = start_ns;
  int64_t next_status_ns = start_ns;
  int64_t last_tool_ns = -client_timeout_ns;
  uint64_t last_tool_seq = 0;
  int64_t last_tool_stamp_ns = 0;
  int64_t last_tool_receive_ns = 0;
  uint64_t last_cuts = simulation->Tool().cuts;  // not 0 after --resume
  int exit_code = 0;

  while (!g_stop) {
    if (options_.duration && simulation->sim_time() >= *options_.duration - 1e-9) break;
    const int64_t frame_start = MonotonicNs();

    // Frame order, for the pose-to-model latency: the newest tool pose is
    // taken right before the step (after the pacing sleep, so a pose that
    // arrived while we slept is not a frame late), the local model goes out
    // right after the step, and only then recording, viewers and status.
    // Tool poses: the newest valid one drives the blade (stale ones dropped).
    std::optional<sim::ToolPose> applied;
    if (const auto tool = link.PollTool()) {
      applied = sim::ToolPose{tool->tip, tool->blade_dir};
      simulation->SetToolPose(*applied);
      last_tool_ns = frame_start;
      last_tool_seq = tool->seq;
      last_tool_stamp_ns = tool->stamp_ns;
      last_tool_receive_ns = tool->receive_ns;
      ++counters.tool_messages;
    }
    const bool client_present = frame_start - last_tool_ns < client_timeout_ns;

    if (simulation->AdvanceFrame(frame_dt) != sim::SimStatus::kOk) {
      Log().error("simulation stopped: {}", simulation->Summary().diagnosis);
      exit_code = 3;
      break;
    }
    ++counters.frames;

    // The local model only when a haptic client listens (seed §3.4).
    if (client_present && simulation->has_tool()) {
      const sim::ToolReport tool = simulation->Tool();
      haptics::ModelHeader header;
      header.stamp_ns = MonotonicNs();
      header.sim_time = simulation->sim_time();
      header.valid_for = 2.0 * frame_dt;
      header.cut.cuts = tool.cuts;
      header.cut.cutting = tool.cuts > last_cuts;
      header.cut.decay_per_second = hp.decay_per_second();
      header.topology_version = simulation->topology_version();
      haptics::ContactLinearisation contact;
      contact.contact = tool.touching;
      if (tool.touching) {
        contact.x0 = tool.pose.tip;
        contact.normal = tool.normal;
        contact.f0 = tool.force_on_tool;
        contact.stiffness = simulation->ContactStiffness();
      }
      link.PublishModel(haptics::BuildLocalModel(header, contact), last_tool_seq);
      // Latency only for a model computed from a pose taken this frame. A
      // frame without a new pose (the client paused or ended, within its
      // timeout) still refreshes the model, but answers no pose: measured
      // against the last one it would add the pause (up to the timeout).
      if (applied) {
        const int64_t published_ns = MonotonicNs();
        latency.pose_to_model.Add(1e-9 * static_cast<double>(published_ns - last_tool_stamp_ns));
        latency.receive_to_model.Add(1e-9 * static_cast<double>(published_ns - last_tool_receive_ns));
      }
      ++counters.models_published;
      last_cuts = tool.cuts;
    }
    if (recorder) recorder->Frame(frame_dt, applied, *simulation);  // after the model: off the latency path

    // Viewers at their own rate; nothing is encoded while none is matched.
    if (frame_start >= next_viewer_ns) {
      next_viewer_ns += viewer_period_ns;
      if (next_viewer_ns < frame_start) next_viewer_ns = frame_start + viewer_period_ns;
      publisher.PublishFrame([&](transport::MeshFrame& frame) {
        // Swap rather than copy: `view` and `frame` trade buffers each frame,
        // so once warm neither allocates and the mesh is copied only once.
        simulation->FillMeshView(view);
        frame.frame = counters.frames;
        frame.sim_time = simulation->sim_time();
        frame.topology_version = simulation->topology_version();
        frame.world.swap(view.world);
        frame.rest.swap(view.rest);
        frame.tets.swap(view.tets);
        frame.surface.swap(view.surface);
        frame.opened.swap(view.opened);
        frame.stress.clear();
      });
      ++counters.viewer_frames;
    }
    if (frame_start >= next_status_ns) {
      next_status_ns = frame_start + 1'000'000'000;
      if (publisher.HasReaders()) {
        const auto s = simulation->QuickSummary();
        v1::SessionStatus status;
        status.set_session(options_.session);
        status.set_frame(counters.frames);
        status.set_sim_time(s.sim_time);
        status.set_wall_time(1e-9 * static_cast<double>(frame_start - start_ns));
        status.set_steps(static_cast<uint64_t>(s.steps));
        status.set_dt(s.dt);
        status.set_topology_version(s.topology_version);
        status.set_cuts(s.cuts);
        status.set_kinetic_energy(s.kinetic_energy);
        status.set_frame_overruns(counters.overruns);
        status.set_tool_messages(counters.tool_messages);
        publisher.PublishStatus(status);
      }
    }
    if (g_print_stats) {
      g_print_stats = 0;
      Log().info("stats: {}", StatsJson(options_, simulation->Summary(), counters, frame_time, latency,
                                        link.stats(), publisher.stats()));
    }

    checkpointer.MaybeSave(*simulation);

    // Pace to the wall clock on absolute deadlines. An overrun drops the
    // missed slot instead of catching up: the next frame starts at once and
    // the deadlines restart from now, so a slow frame never leaves a backlog
    // of frames run back to back.
    const int64_t end = MonotonicNs();
    frame_time.Add(1e-9 * static_cast<double>(end - frame_start));
    deadline += frame_ns;
    if (fifo_permitted && end - window_start_ns >= kFifoWindowNs) {
      const int64_t cpu_ns = ThreadCpuNs();
      const double busy =
          static_cast<double>(cpu_ns - window_cpu_start_ns) / static_cast<double>(end - window_start_ns);
      if (physics_fifo && busy > kMaxFifoBusy) {
        physics_fifo = false;
        (void)transport::SetCurrentThreadNormal();
        Log().warn("the physics used {:.0f}% of a core over the last second: SCHED_OTHER until it needs "
                   "less than {:.0f}%, so it cannot starve other threads",
                   100.0 * busy, 100.0 * kResumeFifoBusy);
      } else if (!physics_fifo && busy < kResumeFifoBusy) {
        physics_fifo = transport::SetCurrentThreadFifo(transport::kServerPhysicsPriority) == 0;
        if (physics_fifo) Log().info("the physics used {:.0f}% of a core: back to SCHED_FIFO", 100.0 * busy);
      }
      window_start_ns = end;
      window_cpu_start_ns = cpu_ns;
    }
    if (end > deadline) {
      ++counters.overruns;
      deadline = end;
    } else {
      SleepUntilNs(deadline);
    }
  }
  link.StopReceiving();

  if (recorder) {
    const uint64_t hash = recorder->Finish(*simulation);
    Log().info("recorded {} frames to {} (final mesh hash {:016x})", recorder->frames(), options_.record, hash);
  }
  if (exit_code == 0) (void)checkpointer.Save(*simulation);  // clean exit, SIGTERM included
  const std::string json = StatsJson(options_, simulation->Summary(), counters, frame_time, latency,
                                     link.stats(), publisher.stats());
  Log().info("session ended: {}", json);
  std::printf("%s\n", json.c_str());
  if (!options_.stats_json.empty()) {
    const std::string tmp = options_.stats_json + ".tmp";
    std::ofstream(tmp) << json << "\n";
    std::filesystem::rename(tmp, options_.stats_json);
  }
  if (!options_.out.empty()) simulation->WriteVtu(options_.out);
  return exit_code;
}

}  // namespace cutsim::server

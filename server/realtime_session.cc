// The real-time session: physics paced to the wall clock, tool poses in and
// local models out over LCM (the haptic station renders the local "buffer
// model" between frames), mesh frames out to any number of viewers over DDS.
// Thin glue: the work is in common/.
#include <algorithm>
#include <chrono>
#include <cmath>
#include <csignal>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <memory>
#include <optional>
#include <string>
#include <vector>

#include "common/core/clock.h"
#include "common/core/error.h"
#include "common/core/input_file.h"
#include "common/core/log.h"
#include "common/core/stop.h"
#include "common/haptics/local_model.h"
#include "common/sim/checkpointer.h"
#include "common/sim/metrics_proto.h"
#include "server/history.h"
#include "server/session_report.h"
#include "common/sim/scene_loader.h"
#include "common/sim/simulation.h"
#include "common/transport/channels.h"
#include "common/transport/dds.h"
#include "common/transport/haptic_link.h"
#include "common/transport/lcm_bus.h"
#include "common/transport/lcm_packet.h"
#include "common/transport/stream_auth.h"
#include "common/transport/mesh_stream.h"
#include "common/transport/proto_vec.h"
#include "common/transport/realtime_thread.h"
#include "common/transport/report_json.h"
#include "common/transport/server_presence.h"
#include "cutsim/v1/report.pb.h"
#include "server/frame_profile.h"
#include "server/observed_plan.h"
#include "server/recorder.h"
#include "server/server_app.h"

namespace cutsim::server {

extern volatile std::sig_atomic_t g_print_stats;

namespace {

using transport::ReportCount;

/// Frame-time statistics kept in a preallocated ring (no allocation per frame).
class FrameStats {
 public:
  explicit FrameStats(size_t capacity) : samples_(capacity) {}
  void Add(double seconds) {
    samples_[next_ % samples_.size()] = seconds;
    ++next_;
    max_ = std::max(max_, seconds);
  }
  /// Allocates: for reports, not for the frame loop.
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
  uint64_t late_overruns = 0;  ///< Overruns after the session's first second.
  uint64_t tool_messages = 0;  ///< Frames that applied a fresh tool pose.
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

/// The newest tool pose the physics applied, and when it was taken.
struct AppliedTool {
  int64_t frame_ns = 0;    ///< Monotonic start of the frame that applied it.
  uint64_t seq = 0;        ///< The station's sequence number.
  int64_t stamp_ns = 0;    ///< The station's device read (its monotonic clock).
  int64_t receive_ns = 0;  ///< Accepted by the link's receive thread.
};

/// "file://<absolute path>", or "" (Cyclone's default) for no file.
std::string DdsConfigUri(const std::string& file) {
  return file.empty() ? std::string() : "file://" + std::filesystem::absolute(file).string();
}

/// The frame loop of a real-time session and its statistics. Lives on the
/// physics thread; once warm a frame allocates nothing (the publisher's mesh
/// frame is reused, the statistics rings are preallocated).
class RealtimeLoop {
 public:
  struct Parts {
    sim::Simulation& simulation;
    transport::HapticServerLink& link;
    transport::MeshStreamPublisher& publisher;
    SessionRecorder* recorder;  // null: not recording
    sim::PeriodicCheckpointer& checkpointer;
    transport::FifoGovernor& governor;
  };

  RealtimeLoop(const ServerOptions& options, double frame_dt, double decay_per_second, Parts parts);

  /// Runs frames until a signal, --duration or a failed frame; returns the
  /// exit code (0, or 3 when the simulation stopped).
  int Run();
  [[nodiscard]] v1::ServerSessionStats Stats() const;

 private:
  std::optional<sim::ToolPose> TakeToolPose(int64_t frame_start);
  void PublishLocalModel(bool pose_this_frame);
  void PublishViewerFrame(int64_t frame_start);
  /// Fills `observed_`: the session as observers see it at this frame
  /// (clock, cuts, tool), in place (protobuf keeps the tool message).
  void FillObserved(int64_t frame_start);
  void PublishStatus(int64_t frame_start);
  void Pace(int64_t frame_start);

  const ServerOptions& options_;
  const double frame_dt_;
  const double decay_per_second_;
  Parts p_;
  const int64_t frame_ns_;
  const int64_t viewer_period_ns_;
  const int64_t client_timeout_ns_;
  const int64_t start_ns_;
  int64_t deadline_ns_;
  int64_t next_viewer_ns_;
  int64_t next_status_ns_;
  AppliedTool tool_;
  uint64_t last_cuts_;
  bool client_was_present_ = false;  // for the connected / gone log lines
  SessionCounters counters_;
  FrameStats frame_time_{1 << 16};
  LatencyStats latency_;
  FrameProfile profile_;
  v1::ObserverSession observed_;  // reused every viewer frame
  int64_t next_plan_ns_ = 0;      // when observers get the planned line again
};

RealtimeLoop::RealtimeLoop(const ServerOptions& options, double frame_dt, double decay_per_second,
                           Parts parts)
    : options_(options),
      frame_dt_(frame_dt),
      decay_per_second_(decay_per_second),
      p_(parts),
      frame_ns_(static_cast<int64_t>(std::llround(frame_dt * 1e9))),
      viewer_period_ns_(static_cast<int64_t>(std::llround(1e9 / options.viewer_fps))),
      client_timeout_ns_(static_cast<int64_t>(options.client_timeout * 1e9)),
      start_ns_(MonotonicNs()),
      deadline_ns_(start_ns_),
      next_viewer_ns_(start_ns_),
      next_status_ns_(start_ns_),
      tool_{.frame_ns = -client_timeout_ns_},
      last_cuts_(parts.simulation.Tool().cuts) {}  // not 0 after --resume

int RealtimeLoop::Run() {
  sim::Simulation& simulation = p_.simulation;
  while (!StopRequested()) {
    if (options_.duration && simulation.sim_time() >= *options_.duration - 1e-9) break;
    const int64_t frame_start = MonotonicNs();
    profile_.BeginFrame(frame_start);
    // Frame order, for the pose-to-model latency: the newest tool pose is
    // taken right before the step (after the pacing sleep, so a pose that
    // arrived during it is not a frame late), the local model goes out right
    // after the step, and only then recording, viewers and status.
    const std::optional<sim::ToolPose> applied = TakeToolPose(frame_start);
    profile_.End(ServerStage::kToolPose, MonotonicNs());
    const bool client_present = frame_start - tool_.frame_ns < client_timeout_ns_;
    if (client_present != client_was_present_) {
      client_was_present_ = client_present;
      if (client_present) {
        Log().info("haptic client connected: tool poses arriving (seq {})", tool_.seq);
      } else {
        Log().warn("haptic client gone: no tool pose for {:.3g} s (--client-timeout); last seq {}",
                   options_.client_timeout, tool_.seq);
      }
    }
    if (simulation.AdvanceFrame(frame_dt_) != sim::SimStatus::kOk) {
      Log().error("simulation stopped: {}", simulation.Summary().diagnosis);
      return 3;
    }
    profile_.EndSimulation(simulation.LastFrameTimes(), MonotonicNs());
    ++counters_.frames;
    // The frame's cut goes to the journal's writer thread before the
    // haptic client feels it; the write and fdatasync happen there.
    p_.checkpointer.JournalNewEvents(simulation);
    profile_.End(ServerStage::kJournal, MonotonicNs());
    // The local model only when a haptic client listens.
    if (client_present && simulation.has_tool()) PublishLocalModel(applied.has_value());
    profile_.End(ServerStage::kLocalModel, MonotonicNs());
    if (p_.recorder) p_.recorder->Frame(frame_dt_, applied, simulation);  // off the latency path
    profile_.End(ServerStage::kRecord, MonotonicNs());
    if (frame_start >= next_viewer_ns_) PublishViewerFrame(frame_start);
    profile_.End(ServerStage::kViewer, MonotonicNs());
    if (frame_start >= next_status_ns_) PublishStatus(frame_start);
    profile_.End(ServerStage::kStatus, MonotonicNs());
    if (g_print_stats) {
      g_print_stats = 0;
      Log().info("stats: {}", transport::ReportJson(Stats()));
    }
    p_.checkpointer.MaybeSave(simulation);
    profile_.End(ServerStage::kCheckpoint, MonotonicNs());
    Pace(frame_start);
  }
  return 0;
}

std::optional<sim::ToolPose> RealtimeLoop::TakeToolPose(int64_t frame_start) {
  // The newest valid pose drives the blade (stale ones are dropped).
  const auto tool = p_.link.PollTool();
  if (!tool) return std::nullopt;
  p_.simulation.SetToolPose(tool->pose);
  tool_ = {.frame_ns = frame_start, .seq = tool->seq, .stamp_ns = tool->stamp_ns,
           .receive_ns = tool->receive_ns};
  ++counters_.tool_messages;
  return tool->pose;
}

void RealtimeLoop::PublishLocalModel(bool pose_this_frame) {
  const sim::Simulation& simulation = p_.simulation;
  const sim::ToolReport tool = simulation.Tool();
  haptics::ModelHeader header;
  header.stamp_ns = MonotonicNs();
  header.sim_time = simulation.sim_time();
  header.valid_for = 2.0 * frame_dt_;
  header.cut.cuts = tool.cuts;
  header.cut.cutting = tool.cuts > last_cuts_;
  header.cut.decay_per_second = decay_per_second_;
  header.topology_version = simulation.topology_version();
  haptics::ContactLinearisation contact;
  contact.contact = tool.touching;
  if (tool.touching) {
    contact.x0 = tool.pose.tip;
    contact.normal = tool.normal;
    contact.f0 = tool.force_on_tool;
    contact.stiffness = simulation.ContactStiffness();
  }
  p_.link.PublishModel(haptics::BuildLocalModel(header, contact), tool_.seq);
  // Latency only for a model computed from a pose taken this frame. A frame
  // without a new pose (the client paused or ended, within its timeout)
  // still refreshes the model but answers no pose: measured against the
  // last one it would add the pause (up to the timeout).
  if (pose_this_frame) {
    const int64_t published_ns = MonotonicNs();
    latency_.pose_to_model.Add(1e-9 * static_cast<double>(published_ns - tool_.stamp_ns));
    latency_.receive_to_model.Add(1e-9 * static_cast<double>(published_ns - tool_.receive_ns));
  }
  ++counters_.models_published;
  last_cuts_ = tool.cuts;
}

void RealtimeLoop::FillObserved(int64_t frame_start) {
  v1::ObserverSession& o = observed_;
  o.Clear();
  o.set_sim_time(p_.simulation.sim_time());
  o.set_wall_time(1e-9 * static_cast<double>(frame_start - start_ns_));
  // The wall clock, unlike the monotonic one, is shared with a browser on
  // the same host: it gives the glass-to-glass latency.
  o.set_publish_unix_ns(
      std::chrono::duration_cast<std::chrono::nanoseconds>(std::chrono::system_clock::now().time_since_epoch())
          .count());
  o.set_topology_version(p_.simulation.topology_version());
  // The plan about once a second: a page that joins has it within a second.
  if (frame_start >= next_plan_ns_) {
    next_plan_ns_ = frame_start + 1'000'000'000;
    if (const sim::PlannedIncision* plan = p_.simulation.Plan()) FillPlannedLine(*plan, o.mutable_plan());
  }
  FillObservedSession(p_.simulation, &o);
}

void RealtimeLoop::PublishViewerFrame(int64_t frame_start) {
  // Viewers at their own rate; nothing is encoded while none is matched.
  next_viewer_ns_ += viewer_period_ns_;
  if (next_viewer_ns_ < frame_start) next_viewer_ns_ = frame_start + viewer_period_ns_;
  // The simulation fills the publisher's reused frame in place: once warm
  // nothing allocates, and the mesh is copied once.
  FillObserved(frame_start);
  p_.publisher.SetObserved(observed_);
  p_.publisher.PublishFrame([this](transport::MeshFrame& frame) {
    p_.simulation.FillMeshView(frame);
    frame.frame = counters_.frames;
    frame.sim_time = p_.simulation.sim_time();
    frame.topology_version = p_.simulation.topology_version();
    frame.stress.clear();
  });
  ++counters_.viewer_frames;
}

void RealtimeLoop::PublishStatus(int64_t frame_start) {
  next_status_ns_ = frame_start + 1'000'000'000;
  if (!p_.publisher.HasStatusReaders()) return;
  const auto s = p_.simulation.QuickSummary();
  v1::SessionStatus status;
  status.set_session(options_.session);
  status.set_frame(counters_.frames);
  status.set_sim_time(s.sim_time);
  status.set_wall_time(1e-9 * static_cast<double>(frame_start - start_ns_));
  status.set_steps(static_cast<uint64_t>(s.steps));
  status.set_dt(s.dt);
  status.set_topology_version(s.topology_version);
  status.set_cuts(s.cuts);
  status.set_kinetic_energy(s.kinetic_energy);
  status.set_frame_overruns(counters_.overruns);
  status.set_tool_messages(counters_.tool_messages);
  status.set_scene(std::filesystem::path(options_.scene).stem().string());
  status.set_trainee(options_.trainee);
  if (const auto score = p_.simulation.Score()) *status.mutable_score() = *score;
  p_.publisher.PublishStatus(status);
}

void RealtimeLoop::Pace(int64_t frame_start) {
  // Absolute deadlines. An overrun drops the missed slot instead of catching
  // up: the next frame starts at once and the deadlines restart from now, so
  // a slow frame never leaves a backlog of frames run back to back.
  const int64_t end = MonotonicNs();
  frame_time_.Add(1e-9 * static_cast<double>(end - frame_start));
  deadline_ns_ += frame_ns_;
  p_.governor.Update(end);
  profile_.EndFrame(counters_.frames, p_.simulation.sim_time(), 1e-9 * static_cast<double>(end - frame_start),
                    end > deadline_ns_);
  if (end > deadline_ns_) {
    ++counters_.overruns;
    if (end - start_ns_ > 1'000'000'000) ++counters_.late_overruns;
    deadline_ns_ = end;
  } else {
    SleepUntilNs(deadline_ns_);
  }
}

v1::ServerSessionStats RealtimeLoop::Stats() const {
  const transport::HapticServerLinkStats link = p_.link.stats();
  const transport::MeshStreamStats mesh = p_.publisher.stats();
  v1::ServerSessionStats r;
  // The summary's entries first; the loop's own counts (its frames) after.
  sim::SummaryToReport(p_.simulation.Summary(), &r);
  r.set_session(options_.session);
  r.set_frames(ReportCount(counters_.frames));
  r.set_frame_overruns(ReportCount(counters_.overruns));
  r.set_frame_overruns_after_first_second(ReportCount(counters_.late_overruns));
  r.set_frame_time_p50_ms(1e3 * frame_time_.Percentile(0.5));
  r.set_frame_time_p99_ms(1e3 * frame_time_.Percentile(0.99));
  r.set_frame_time_max_ms(1e3 * frame_time_.max());
  r.set_pose_to_model_p50_ms(1e3 * latency_.pose_to_model.Percentile(0.5));
  r.set_pose_to_model_p99_ms(1e3 * latency_.pose_to_model.Percentile(0.99));
  r.set_pose_to_model_max_ms(1e3 * latency_.pose_to_model.max());
  r.set_receive_to_model_p50_ms(1e3 * latency_.receive_to_model.Percentile(0.5));
  r.set_receive_to_model_p99_ms(1e3 * latency_.receive_to_model.Percentile(0.99));
  r.set_pose_latency_samples(ReportCount(latency_.pose_to_model.count()));
  r.set_frames_with_pose(ReportCount(counters_.tool_messages));
  r.set_tool_messages(ReportCount(link.accepted));
  r.set_tool_rejected(ReportCount(link.foreign_session + link.stale + link.duplicate + link.invalid +
                                  link.decode_errors + link.unauthenticated));
  r.set_models_published(ReportCount(counters_.models_published));
  r.set_viewer_frames(ReportCount(mesh.frames));
  r.set_viewer_frames_without_reader(ReportCount(mesh.skipped_no_reader));
  r.set_snapshots(ReportCount(mesh.snapshots));
  r.set_deltas(ReportCount(mesh.deltas));
  r.set_tool_unsigned(ReportCount(link.auth_unsigned));
  r.set_tool_forged(ReportCount(link.auth_forged));
  r.set_tool_replayed(ReportCount(link.auth_replayed));
  *r.mutable_metrics() = p_.simulation.Metrics();
  if (const auto score = p_.simulation.Score()) *r.mutable_score() = *score;
  FillJournalStats(p_.checkpointer, r.mutable_journal());
  transport::ToReport(link.packets, r.mutable_tool_packets());
  r.set_models_signed(p_.link.signs_models());
  profile_.AddToStats(r);
  return r;
}

}  // namespace

int ServerApp::RunRealtime() {
  transport::ValidateSessionName(options_.session, "--session");
  // One server per session: ask who is there before touching the
  // checkpoint or any output, and keep announcing this server while it runs.
  transport::ServerPresence presence(
      {.lcm_url = options_.lcm_url, .session = options_.session, .key = transport::LoadSessionKey(options_.key_file)});
  if (!ClaimSession(presence, options_.session, "Stop that server, or give this one another --session.")) {
    return transport::kExitDuplicateServer;
  }
  const sim::LoadedScene scene = sim::LoadScene(options_.scene);
  const double frame_dt =
      options_.frame_rate > 0 ? 1.0 / options_.frame_rate : scene.scene.time_step().frame_dt();
  // A wall-clock budget makes a step depend on timing; a recorded session
  // keeps every step at its tolerance (so its replay is exact) unless
  // --frame-budget asks for one.
  const double budget = options_.frame_budget >= 0 ? options_.frame_budget
                        : options_.record.empty()   ? kDefaultFrameBudget
                                                    : 0.0;
  if (budget > 0) {
    Log().info("frame budget: the implicit step stops at {:.3g} ms of each {:.3g} ms frame (--frame-budget {:.2g})",
               1e3 * budget * frame_dt, 1e3 * frame_dt, budget);
  }
  auto simulation = sim::Simulation::Create(scene, {.threads = options_.threads,
                                                    .precision = options_.precision,
                                                    .integrator = options_.integrator,
                                                    .frame_budget = budget * frame_dt});
  const auto signer = MakeJournalSigner(options_);
  sim::PeriodicCheckpointer checkpointer(options_.checkpoint, options_.checkpoint_every, signer.get());
  (void)checkpointer.Begin(*simulation, options_.resume);

  // The haptic link. LCM's udpm receive thread starts on the first
  // subscription and inherits this scope's SCHED_FIFO priority (when
  // permitted), so poses reach the link while the physics computes.
  const auto authenticator = MakeToolAuthenticator(options_);  // null: an open session
  // The local models are signed with the same key; the station checks them.
  std::optional<transport::PayloadAuthenticator> model_signer;
  if (const auto key = transport::LoadSessionKey(options_.key_file)) {
    model_signer.emplace(*key, transport::kHapticModelDomain, options_.session);
    Log().info("session '{}': local models are signed (HMAC-SHA256 trailer, epoch and 2 s window)",
               options_.session);
  }
  const int lcm_priority = options_.realtime_priority ? transport::kLcmThreadPriority : 0;
  transport::ScopedThreadFifo lcm_scope(lcm_priority);
  transport::LcmBus bus(options_.lcm_url);
  transport::HapticServerLink link(
      bus, options_.session,
      {.authenticator = authenticator.get(), .model_auth = model_signer ? &*model_signer : nullptr});
  lcm_scope.Restore();
  auto recorder = options_.record.empty() ? nullptr
                                          : std::make_unique<SessionRecorder>(
                                                options_.record, options_.session, options_.scene, *simulation);
  transport::DdsParticipant participant(options_.dds_domain, DdsConfigUri(options_.dds_config));
  // Observer frames are signed with the session key when there is one.
  transport::MeshStreamPublisher publisher(participant, options_.session,
                                           {.key = transport::LoadSessionKey(options_.key_file)});
  // Poses arrive on their own thread; the physics takes the newest right
  // before each step.
  link.StartReceiving(lcm_priority);
  // The physics thread runs SCHED_FIFO below the LCM threads and the haptic
  // loop, set after every helper thread (DDS, LCM) exists so none inherits it.
  transport::FifoGovernor governor(options_.realtime_priority ? transport::kServerPhysicsPriority : 0,
                                   "physics thread", "frames and the local model");
  Log().info("session '{}': physics {:.0f} Hz, viewers {:.0f} Hz, LCM {}, DDS domain {}",
             options_.session, 1.0 / frame_dt, options_.viewer_fps, options_.lcm_url,
             options_.dds_domain);

  RealtimeLoop loop(options_, frame_dt, scene.scene.haptics().decay_per_second(),
                    {*simulation, link, publisher, recorder.get(), checkpointer, governor});
  const int exit_code = loop.Run();
  link.StopReceiving();
  if (presence.refused()) {
    // Another server started first: its checkpoint and outputs are not ours to write.
    Log().error("session '{}': stopped for the server that started first; no checkpoint or "
                "outputs written",
                options_.session);
    return transport::kExitDuplicateServer;
  }

  // Every output is finished and checked; a lost one makes the exit non-zero
  // (kExitOutputFailed) after the others are written.
  bool outputs_ok = true;
  if (recorder) {
    try {
      const uint64_t hash = recorder->Finish(*simulation);
      Log().info("recorded {} frames to {} (final mesh hash {:016x})", recorder->frames(), options_.record, hash);
    } catch (const InputError& e) {
      Log().error("recording lost: {}", e.what());
      outputs_ok = false;
    }
  }
  if (exit_code == 0 && checkpointer.enabled() && !checkpointer.Save(*simulation)) outputs_ok = false;
  outputs_ok &= FinishJournal(checkpointer);
  if (checkpointer.failures() > 0) {
    Log().warn("{} of {} checkpoint saves to {} failed", checkpointer.failures(),
               checkpointer.failures() + checkpointer.saves(), options_.checkpoint);
  }
  const std::string json = transport::ReportJson(loop.Stats());
  Log().info("session ended: {}", json);
  std::printf("%s\n", json.c_str());
  if (std::fflush(stdout) != 0) outputs_ok = false;
  if (!options_.stats_json.empty()) outputs_ok &= WriteOutput([&] { WriteFileAtomically(options_.stats_json, json + "\n"); });
  if (!options_.session_report.empty()) {
    outputs_ok &= WriteOutput([&] {
      WriteSessionReport(options_.session_report, MakeSessionReport(*simulation, options_.session, scene.scene.name()));
    });
  }
  if (!options_.out.empty()) outputs_ok &= WriteOutput([&] { simulation->WriteVtu(options_.out); });
  // Last: a locked history may hold the exit for its busy timeout.
  if (!options_.history.empty() && exit_code == 0) {
    (void)AppendToHistory(options_.history, options_.trainee, options_.session, scene.scene.name(), *simulation);
  }
  return exit_code != 0 ? exit_code : outputs_ok ? 0 : kExitOutputFailed;
}

}  // namespace cutsim::server

// The debrief: a recording re-simulated at real pace and published as a live
// session (`cutsim-server --replay FILE --live`), so viewers, their browsers
// and the trainee page watch it. Commands (common/debrief/debrief_command.h)
// arrive on standard input and, from the instructor's page through the
// browser bridge, on the session's DDS control topic. Thin glue: the player
// is common/debrief, the stream common/transport.
#include <poll.h>
#include <unistd.h>

#include <algorithm>
#include <atomic>
#include <chrono>
#include <cmath>
#include <csignal>
#include <cstdio>
#include <deque>
#include <filesystem>
#include <mutex>
#include <optional>
#include <string>
#include <thread>
#include <vector>

#include "common/core/clock.h"
#include "common/core/error.h"
#include "common/core/log.h"
#include "common/core/stop.h"
#include "common/debrief/debrief_command.h"
#include "common/debrief/debrief_player.h"
#include "common/sim/metrics_proto.h"
#include "common/sim/scene_loader.h"
#include "common/transport/channels.h"
#include "common/transport/dds.h"
#include "common/transport/debrief_control.h"
#include "common/transport/mesh_publisher.h"
#include "common/transport/mesh_stream.h"
#include "common/transport/proto_vec.h"
#include "common/transport/report_json.h"
#include "common/transport/server_presence.h"
#include "common/transport/stream_auth.h"
#include "server/observed_plan.h"
#include "server/recorder.h"
#include "server/server_app.h"
#include "server/session_report.h"

namespace cutsim::server {


namespace {

/// Lines typed on standard input, read on a thread of their own (poll with
/// a timeout, so it ends with the session). A line longer than the
/// language allows is dropped whole and reported as such.
class StdinLines {
 public:
  StdinLines() : thread_([this] { Run(); }) {}
  ~StdinLines() {
    done_ = true;
    thread_.join();
  }
  StdinLines(const StdinLines&) = delete;
  StdinLines& operator=(const StdinLines&) = delete;

  /// The lines read since the last call.
  std::vector<std::string> Take() {
    const std::lock_guard lock(mu_);
    std::vector<std::string> out(lines_.begin(), lines_.end());
    lines_.clear();
    return out;
  }

 private:
  void Run() {
    std::string line;
    bool overlong = false;
    char buffer[256];
    while (!done_) {
      pollfd p{.fd = STDIN_FILENO, .events = POLLIN, .revents = 0};
      if (::poll(&p, 1, 100) <= 0) continue;
      const ssize_t n = ::read(STDIN_FILENO, buffer, sizeof buffer);
      if (n <= 0) return;  // end of input: commands come from the page only
      for (ssize_t i = 0; i < n; ++i) {
        if (buffer[i] != '\n') {
          if (line.size() <= debrief::kMaxCommandBytes) line.push_back(buffer[i]);
          else overlong = true;
          continue;
        }
        Push(overlong ? std::string(debrief::kMaxCommandBytes + 1, '?') : line);
        line.clear();
        overlong = false;
      }
    }
  }
  void Push(std::string line) {
    const std::lock_guard lock(mu_);
    if (lines_.size() < 64) lines_.push_back(std::move(line));
  }

  std::atomic<bool> done_{false};
  std::mutex mu_;
  std::deque<std::string> lines_;
  std::thread thread_;
};

/// The timeline as observers receive it.
void TimelineToProto(const debrief::Timeline& t, v1::DebriefTimeline* out) {
  out->set_duration(t.duration);
  out->set_tolerance(t.tolerance);
  const auto fill = [](const std::vector<double>& from, google::protobuf::RepeatedField<float>* to) {
    const size_t n = std::min<size_t>(from.size(), 4096);
    to->Reserve(static_cast<int>(n));
    for (size_t i = 0; i < n; ++i) to->Add(static_cast<float>(from[i]));
  };
  fill(t.force_t, out->mutable_force_t());
  fill(t.force_n, out->mutable_force_n());
  fill(t.cut_t, out->mutable_cut_t());
  fill(t.cut_deviation, out->mutable_cut_deviation());
  fill(t.step_t, out->mutable_step_t());
}

/// The play loop: the playhead moves with the wall clock × speed while
/// playing; the player steps up to it; viewers get frames at their rate.
class DebriefLoop {
 public:
  DebriefLoop(const ServerOptions& options, const Recording& recording, debrief::DebriefPlayer& player,
              transport::MeshStreamPublisher& publisher, transport::DebriefControlReader& control)
      : options_(options),
        recording_(recording),
        scene_name_(std::filesystem::path(recording.scene).stem().string()),
        player_(player),
        publisher_(publisher),
        control_(control),
        viewer_period_ns_(static_cast<int64_t>(std::llround(1e9 / options.viewer_fps))),
        start_ns_(MonotonicNs()) {}

  void Run() {
    StdinLines stdin_lines;
    int64_t last_ns = MonotonicNs();
    int64_t next_viewer_ns = last_ns;
    int64_t next_status_ns = last_ns;
    while (!StopRequested()) {
      for (const std::string& line : stdin_lines.Take()) Apply(line, "standard input");
      control_.Poll(std::chrono::nanoseconds(0), [this](const std::string& line) { Apply(line, "the page"); });
      const int64_t now = MonotonicNs();
      if (!paused_) playhead_ += 1e-9 * static_cast<double>(now - last_ns) * speed_;
      last_ns = now;
      if (playhead_ >= player_.duration()) {
        playhead_ = player_.duration();
        if (!paused_ && player_.at_end()) {
          paused_ = true;
          Log().info("debrief: the recording ended at {:.3f} s (seek, prev or play to go on)", player_.duration());
        }
      }
      StepToPlayhead(now);
      if (now >= next_viewer_ns || publish_now_) {
        next_viewer_ns = std::max(next_viewer_ns + viewer_period_ns_, now);
        PublishFrame(now);
      }
      if (now >= next_status_ns) {
        next_status_ns = now + 1'000'000'000;
        PublishStatus(now);
      }
      SleepUntilNs(std::min(next_viewer_ns, MonotonicNs() + 5'000'000));
    }
  }

  /// What the debrief did, as JSON: frames shown and checked against the
  /// live session's hashes, commands, seeks and their cost.
  [[nodiscard]] std::string SummaryJson() const {
    return fmt::format(
        R"({{"session": "{}", "duration": {:.6g}, "frames_stepped": {}, "hash_checks": {}, "hash_mismatches": {}, )"
        R"("commands": {}, "refused": {}, "seeks": {}, "seek_max_ms": {:.1f}, "seek_mean_ms": {:.1f}, )"
        R"("behind_real_time": {}}})",
        options_.session, player_.duration(), frames_stepped_, hash_checks_, hash_mismatches_, commands_, refused_,
        seeks_, 1e3 * seek_max_s_, seeks_ ? 1e3 * seek_total_s_ / static_cast<double>(seeks_) : 0.0, late_);
  }
  [[nodiscard]] uint64_t hash_mismatches() const { return hash_mismatches_; }

 private:
  /// Steps frames up to the playhead within a viewer period of wall time;
  /// a machine slower than the speed asks for drops the backlog (the
  /// playhead waits for the picture) instead of running behind for good.
  void StepToPlayhead(int64_t now) {
    const int64_t budget_end = now + viewer_period_ns_;
    while (!player_.at_end() && player_.position() < playhead_ - 1e-9) {
      player_.StepFrame();  // ends at most one frame past the playhead
      ++frames_stepped_;
      CheckHash();
      if (MonotonicNs() > budget_end) {
        playhead_ = player_.position();
        ++late_;
        break;
      }
    }
  }

  /// One command line from `source`; a refusal is logged naming the field.
  void Apply(const std::string& line, const char* source) {
    const debrief::CommandParse parse = debrief::ParseDebriefCommand(line);
    if (!parse.command) {
      ++refused_;
      Log().warn("debrief: command from {} refused: {}: {}", source, parse.field, parse.error);
      return;
    }
    const debrief::DebriefCommand& c = *parse.command;
    switch (c.action) {
      case debrief::DebriefAction::kPlay:
        if (player_.at_end()) Seek(0.0);
        paused_ = false;
        break;
      case debrief::DebriefAction::kPause:
        paused_ = true;
        playhead_ = player_.position();
        break;
      case debrief::DebriefAction::kSeek:
        Seek(c.time);
        break;
      case debrief::DebriefAction::kNextStep:
      case debrief::DebriefAction::kPreviousStep: {
        const auto t = c.action == debrief::DebriefAction::kNextStep ? player_.NextStep() : player_.PreviousStep();
        paused_ = true;  // a cut step is there to be looked at
        if (t) {
          Seek(*t);
        } else {
          playhead_ = player_.position();
          Log().info("debrief: no {} cut step from {:.3f} s", c.action == debrief::DebriefAction::kNextStep
                                                                  ? "next" : "previous", player_.position());
        }
        break;
      }
      case debrief::DebriefAction::kSpeed:
        speed_ = c.speed;
        break;
    }
    ++commands_;
    last_command_ = debrief::FormatDebriefCommand(c);
    publish_now_ = true;
    Log().info("debrief: {} (from {}): at {:.3f} s, {}, speed {:g}", last_command_, source, player_.position(),
               paused_ ? "paused" : "playing", speed_);
  }

  /// The frame shown against the live session's hash of it, where the
  /// recording has one.
  void CheckHash() {
    const size_t f = player_.frame();
    if (f == 0 || f > recording_.mesh_hashes.size() || recording_.mesh_hashes[f - 1] == 0) return;
    ++hash_checks_;
    if (RecordingHash(recording_, player_.simulation()) != recording_.mesh_hashes[f - 1]) {
      if (hash_mismatches_++ == 0) {
        Log().error("debrief: frame {} ({:.3f} s) differs from the live session's (mesh hash)", f, player_.position());
      }
    }
  }

  void Seek(double t) {
    const Stopwatch watch;
    const debrief::SeekReport r = player_.Seek(t);
    playhead_ = player_.position();
    const double seconds = watch.ElapsedSeconds();
    ++seeks_;
    seek_total_s_ += seconds;
    seek_max_s_ = std::max(seek_max_s_, seconds);
    CheckHash();
    Log().info("debrief: seek to {:.3f} s in {:.0f} ms: {}{} frames stepped ({:.0f} ms)", player_.position(),
               1e3 * seconds,
               r.restored ? fmt::format("checkpoint at {:.3f} s restored ({:.0f} ms), ", r.restore_from,
                                        1e3 * r.restore_s)
                          : std::string(),
               r.frames_stepped, 1e3 * r.step_s);
  }

  void FillObserved(int64_t now) {
    const sim::Simulation& s = player_.simulation();
    v1::ObserverSession& o = observed_;
    o.Clear();
    o.set_sim_time(s.sim_time());
    o.set_wall_time(1e-9 * static_cast<double>(now - start_ns_));
    o.set_publish_unix_ns(transport::RealtimeNowNs());
    o.set_topology_version(s.topology_version());
    v1::DebriefState* d = o.mutable_debrief();
    d->set_position(player_.position());
    d->set_duration(player_.duration());
    d->set_paused(paused_);
    d->set_speed(speed_);
    d->set_commands(commands_);
    d->set_last_command(last_command_);
    // The timeline about once a second: a page that joins has it within a
    // second, and frames in between stay small.
    // It grows while the checkpoints are made.
    if (now >= next_timeline_ns_) {
      next_timeline_ns_ = now + 1'000'000'000;
      TimelineToProto(player_.timeline(), d->mutable_timeline());
      if (const sim::PlannedIncision* plan = s.Plan()) FillPlannedLine(*plan, o.mutable_plan());
    }
    FillObservedSession(s, &o);
  }

  void PublishFrame(int64_t now) {
    publish_now_ = false;
    FillObserved(now);
    publisher_.SetObserved(observed_);
    publisher_.PublishFrame([this](transport::MeshFrame& frame) {
      const sim::Simulation& s = player_.simulation();
      s.FillMeshView(frame);
      frame.frame = player_.frame();
      frame.sim_time = s.sim_time();
      frame.topology_version = s.topology_version();
      frame.stress.clear();
    });
  }

  void PublishStatus(int64_t now) {
    if (!publisher_.HasStatusReaders()) return;
    const auto q = player_.simulation().QuickSummary();
    v1::SessionStatus status;
    status.set_session(options_.session);
    status.set_frame(player_.frame());
    status.set_sim_time(q.sim_time);
    status.set_wall_time(1e-9 * static_cast<double>(now - start_ns_));
    status.set_steps(static_cast<uint64_t>(q.steps));
    status.set_dt(q.dt);
    status.set_topology_version(q.topology_version);
    status.set_cuts(q.cuts);
    status.set_kinetic_energy(q.kinetic_energy);
    status.set_scene(scene_name_);
    if (const auto score = player_.simulation().Score()) *status.mutable_score() = *score;
    publisher_.PublishStatus(status);
  }

  const ServerOptions& options_;
  const Recording& recording_;
  const std::string scene_name_;
  debrief::DebriefPlayer& player_;
  transport::MeshStreamPublisher& publisher_;
  transport::DebriefControlReader& control_;
  const int64_t viewer_period_ns_;
  const int64_t start_ns_;
  double playhead_ = 0.0;  // s of recorded time the picture should show
  bool paused_ = false;
  double speed_ = 1.0;
  bool publish_now_ = true;
  uint64_t commands_ = 0;
  uint64_t late_ = 0;
  uint64_t refused_ = 0;
  uint64_t frames_stepped_ = 0;
  uint64_t hash_checks_ = 0;
  uint64_t hash_mismatches_ = 0;
  uint64_t seeks_ = 0;
  double seek_total_s_ = 0.0;
  double seek_max_s_ = 0.0;
  std::string last_command_;
  int64_t next_timeline_ns_ = 0;
  v1::ObserverSession observed_;
};

/// "file://<absolute path>", or "" (Cyclone's default) for no file.
std::string ConfigUri(const std::string& file) {
  return file.empty() ? std::string() : "file://" + std::filesystem::absolute(file).string();
}

}  // namespace

int ServerApp::RunDebrief() {
  const Recording recording = ReadRecording(options_.replay, options_.scene);
  if (!options_.session_given) options_.session = recording.header.session();
  transport::ValidateSessionName(options_.session, "--session");
  const auto key = transport::LoadSessionKey(options_.key_file);
  transport::ServerPresence presence({.lcm_url = options_.lcm_url, .session = options_.session, .key = key});
  if (!ClaimSession(presence, options_.session, "Give the debrief another --session.")) {
    return transport::kExitDuplicateServer;
  }
  const sim::LoadedScene scene = sim::LoadScene(recording.scene);
  const sim::SimulationOptions sim_options{.threads = recording.header.threads(),
                                           .precision = recording.header.precision()};
  // The producer: the whole recording once on a thread of its own, checked
  // against it as --replay checks (every frame's topology version, each
  // recorded mesh hash, the final one), while the picture already plays.
  // Its findings are read after it ended (WaitProduced).
  const Stopwatch prepass_watch;
  std::string mismatch;
  uint64_t prepass_hashes = 0;
  std::atomic<bool> ending{false};
  Stopwatch since_progress;
  debrief::DebriefPlayer player(
      [&] { return sim::Simulation::Create(scene, sim_options); }, recording.frames,
      {.checkpoint_every = options_.debrief_checkpoint_every},
      [&](size_t i, const sim::Simulation& s) {
        if (mismatch.empty() && s.topology_version() != recording.frames[i].topology_version) {
          mismatch = fmt::format("frame {}: topology version {}, recorded {}", i + 1, s.topology_version(),
                                 recording.frames[i].topology_version);
        }
        if (recording.mesh_hashes[i] != 0) {
          ++prepass_hashes;
          if (mismatch.empty() && RecordingHash(recording, s) != recording.mesh_hashes[i]) {
            mismatch = fmt::format("frame {}: the mesh hash differs from the recorded one", i + 1);
          }
        }
        if (since_progress.ElapsedSeconds() > 5.0) {
          since_progress.Reset();
          Log().info("debrief: checkpoints made up to {:.1f} s of the recording", s.sim_time());
        }
        if (i + 1 == recording.frames.size()) {
          if (recording.end && mismatch.empty() && RecordingHash(recording, s) != recording.end->mesh_hash()) {
            mismatch = "the final mesh hash differs from the recorded one";
          }
          if (!mismatch.empty()) {
            Log().warn("debrief of {}: the re-run differs from the recording ({}): what observers see is the re-run",
                       options_.replay, mismatch);
          }
          Log().info("debrief of {}: {:.3f} s, {} frames; checkpoints complete (every {:.3g} s), "
                     "pre-pass {:.2f} s; {} recorded mesh hashes {}",
                     options_.replay, s.sim_time(), recording.frames.size(),
                     options_.debrief_checkpoint_every, prepass_watch.ElapsedSeconds(), prepass_hashes,
                     mismatch.empty() ? "all equal" : "checked: " + mismatch);
        }
        return !StopRequested() && !ending;
      });
  Log().info("debrief of {}: {:.3f} s, {} frames; playing from the start while checkpoints are made",
             options_.replay, player.duration(), player.frames());

  transport::DdsParticipant participant(options_.dds_domain, ConfigUri(options_.dds_config));
  transport::MeshStreamPublisher publisher(participant, options_.session, {.key = key});
  transport::DebriefControlReader control(participant, options_.session, key);
  if (!key) {
    Log().warn("debrief '{}' is OPEN: no session key, so any process on the DDS domain can steer it. Give "
               "--key-file (and the same key to the browser bridge) whenever observers are not all on this machine.",
               options_.session);
  }
  Log().info("debrief '{}': playing {} to observers on DDS domain {}; commands on standard input: play, pause, "
             "seek T, next, prev, speed F",
             options_.session, options_.replay, options_.dds_domain);
  DebriefLoop loop(options_, recording, player, publisher, control);
  loop.Run();
  ending = true;
  bool produced = true;
  try {
    player.WaitProduced();
  } catch (const InputError& e) {
    produced = false;
    Log().error("debrief of {}: {}", options_.replay, e.what());
  }
  std::printf("%s\n", loop.SummaryJson().c_str());
  std::fflush(stdout);
  const transport::DebriefControlStats& c = control.stats();
  Log().info("debrief ended: control messages accepted {}, unsigned {}, forged {}, stale {}, malformed {}", c.accepted,
             c.unsigned_samples, c.forged, c.stale, c.malformed);
  if (presence.refused()) return transport::kExitDuplicateServer;
  return loop.hash_mismatches() == 0 && mismatch.empty() && produced ? 0 : 4;
}

}  // namespace cutsim::server

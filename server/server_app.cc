#include "server/server_app.h"

#include <unistd.h>

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <csignal>
#include <filesystem>
#include <functional>

#include <CLI/CLI.hpp>

#include "common/cli/flag_modes.h"
#include "common/core/clock.h"
#include "common/core/error.h"
#include "common/core/input_file.h"
#include "common/core/log.h"
#include "common/core/stop.h"
#include "common/sim/checkpoint.h"
#include "common/sim/checkpointer.h"
#include "common/sim/metrics_proto.h"
#include "common/sim/scene_loader.h"
#include "common/sim/simulation.h"
#include "common/transport/report_json.h"
#include "cutsim/v1/report.pb.h"
#include "server/history.h"
#include "server/recorder.h"
#include "server/session_report.h"

namespace cutsim::server {
volatile std::sig_atomic_t g_print_stats = 0;

namespace {

void OnSignal(int) { RequestStop(); }
void OnStatsSignal(int) { g_print_stats = 1; }

v1::HeadlessSummary HeadlessReport(const sim::Simulation& simulation) {
  v1::HeadlessSummary r;
  sim::SummaryToReport(simulation.Summary(), &r);
  *r.mutable_metrics() = simulation.Metrics();
  if (const auto score = simulation.Score()) *r.mutable_score() = *score;
  return r;
}

v1::ReplayReport MakeReplayReport(const std::string& path, const ReplayResult& result) {
  using transport::ReportCount;
  v1::ReplayReport r;
  r.set_replay(path);
  r.set_session(result.session);
  r.set_scene(result.scene);
  r.set_match(result.match);
  r.set_frames(ReportCount(result.frames));
  r.set_cut_frames(ReportCount(result.cut_frames));
  r.set_cuts(ReportCount(result.cuts));
  r.set_topology_version(ReportCount(result.topology_version));
  r.set_sim_time(result.sim_time);
  r.set_mesh_hash(transport::HexHash(result.mesh_hash));
  r.set_recorded_mesh_hash(transport::HexHash(result.recorded_mesh_hash));
  r.set_build(BuildClass());
  *r.mutable_metrics() = result.metrics;
  if (result.report.has_score()) *r.mutable_score() = result.report.score();
  r.set_status(result.report.status());
  r.set_diagnosis(result.report.diagnosis());
  r.set_unconverged_steps(result.report.unconverged_steps());
  r.set_max_residual_unconverged(result.report.max_residual_unconverged());
  return r;
}

/// The server's modes, in the order of FlagModes' names.
enum ServerMode : int { kRealtimeMode = 0, kHeadlessMode = 1, kReplayMode = 2, kDebriefMode = 3 };
constexpr cli::ModeSet kRealtime = 1U << kRealtimeMode;
constexpr cli::ModeSet kHeadless = 1U << kHeadlessMode;
constexpr cli::ModeSet kReplay = 1U << kReplayMode;
constexpr cli::ModeSet kDebrief = 1U << kDebriefMode;  // a recording played to observers
constexpr cli::ModeSet kRun = kRealtime | kHeadless;  // a simulation this process runs from the scene
constexpr cli::ModeSet kServe = kRealtime | kDebrief;  // a session observers watch over DDS
constexpr cli::ModeSet kAny = kRun | kReplay | kDebrief;

/// The batch-run flags: scene, duration, output, threads, logging.
void AddRunOptions(CLI::App& app, ServerOptions& o, cli::FlagModes& m) {
  m.Declare(app.add_option("--scene", o.scene,
                           "Scene file (protobuf text format); with --replay, overrides the recorded one")
                ->check(CLI::ExistingFile),
            kAny);
  m.Declare(app.add_flag("--headless", o.headless,
                         "Run as fast as possible with no transport, then print a JSON summary"),
            kHeadless | kReplay);
  m.Declare(app.add_option("--duration", o.duration, "Simulated seconds to run")
                ->check(CLI::Range(1e-9, sim::kMaxSimSeconds)),
            kRun);
  m.Declare(app.add_flag("--until-rest", o.until_rest,
                         "Run until kinetic energy and residual force fall below the scene's rest tolerances"),
            kHeadless);
  m.Declare(app.add_option("--max-time", o.max_time, "Cap on simulated seconds for --until-rest")
                ->check(CLI::Range(1e-9, sim::kMaxSimSeconds)),
            kHeadless);
  m.Declare(app.add_option("--out", o.out, "Write the final state to this .vtu file"), kRun);
  m.Declare(app.add_option("--threads", o.threads, "Worker threads (0 = scene/all cores)")
                ->check(CLI::Range(int64_t{0}, sim::kMaxThreads)),
            kRun);
  m.Declare(app.add_option("--precision", o.precision, "Override the scene's precision")
                ->check(CLI::IsMember({"float", "double"})),
            kRun);
  m.Declare(app.add_option("--integrator", o.integrator, "Override the scene's integrator")
                ->check(CLI::IsMember({"explicit", "implicit", "auto"})),
            kRun);
  m.Declare(app.add_option("--frame-budget", o.frame_budget,
                           "Wall-clock budget of a frame's implicit step, as a fraction of the frame: Newton and PCG "
                           "stop there and the residual carries into the next frame (0: none, every step to its "
                           "tolerance; default 0.6 in real time, 0 headless)")
                ->check(CLI::Range(0.0, 1.0)),
            kRun);
  m.Declare(app.add_option("--log-level", o.log_level, "trace, debug, info, warn, error, off"), kAny);
  m.Declare(app.add_flag("!--no-progress", o.progress, "No progress bar (--headless)"), kHeadless);
}

/// The real-time session's flags: session name, LCM and DDS, rates, priority.
void AddRealtimeOptions(CLI::App& app, ServerOptions& o, cli::FlagModes& m) {
  m.Declare(app.add_option("--session", o.session,
                           "Session name (LCM channels, DDS key; the session's name in the score history)"),
            kRun | kDebrief);
  m.Declare(app.add_option("--lcm-url", o.lcm_url,
                           "LCM URL of the haptic link (ttl=0 stays on this host; ttl=1 reaches the LAN)"),
            kServe);
  m.Declare(app.add_option("--dds-domain", o.dds_domain, "DDS domain id for the viewers")->check(CLI::Range(0, 230)),
            kServe);
  m.Declare(app.add_option("--dds-config", o.dds_config,
                           "Cyclone DDS configuration file (default: $CYCLONEDDS_URI, else loopback only)")
                ->check(CLI::ExistingFile),
            kServe);
  m.Declare(app.add_flag("!--no-rt", o.realtime_priority,
                         "Keep the physics and LCM threads at normal priority (default: SCHED_FIFO 60/70 when "
                         "permitted, below the haptic loop's 80); for a machine shared with normal-priority work, "
                         "e.g. a haptic client started with --no-rt"),
            kRealtime);
  m.Declare(app.add_option("--viewer-fps", o.viewer_fps, "Mesh frames per second to viewers")
                ->check(CLI::Range(0.1, 240.0)),
            kServe);
  m.Declare(app.add_option("--frame-rate", o.frame_rate,
                           "Physics frames (local models) per second; default: the scene's time_step.frame_dt")
                ->check(CLI::Range(1.0, 10000.0)),
            kRealtime);
  m.Declare(app.add_option("--stats-json", o.stats_json,
                           "Also write the exit statistics (the JSON summary) to this file"),
            kRun);
}

/// The session report, in every mode.
void AddReportOptions(CLI::App& app, ServerOptions& o, cli::FlagModes& m) {
  m.Declare(app.add_option("--session-report", o.session_report,
                           "At the end, write the session's measures and score to this JSON file and their plot "
                           "beside it (.svg)"),
            kRun | kReplay);
  m.Declare(app.add_option("--history", o.history,
                           "At the end, append the session's score for --trainee to this SQLite file, the lab's "
                           "score history (created when absent; a bad or locked file is logged, never stops the "
                           "session)"),
            kRun);
  m.Declare(app.add_option("--trainee", o.trainee, "Whose session this is, in --history (A-Z a-z 0-9 . _ -, up to 64)"),
            kRun);
}

/// Recording, replay and access control of the tool stream.
void AddRecordAndAccessOptions(CLI::App& app, ServerOptions& o, cli::FlagModes& m) {
  m.Declare(app.add_option("--record", o.record,
                           "Record the session's inputs (tool poses applied, frame times, cuts, final mesh "
                           "hash) to this LCM log"),
            kRealtime);
  m.Declare(app.add_option("--replay", o.replay,
                           "With --headless: re-run a recording and check its cuts and final mesh hash "
                           "(exit 4 on a mismatch); with --live: play it to observers (a debrief)")
                ->check(CLI::ExistingFile),
            kReplay | kDebrief);
  m.Declare(app.add_flag("--live", o.live,
                         "With --replay: re-simulate the recording at real pace and publish it as a live session "
                         "(viewers, browsers, the trainee page watch it); commands on standard input and from the "
                         "instructor's page: play, pause, seek T, next, prev, speed F"),
            kDebrief);
  m.Declare(app.add_option("--key-file", o.key_file,
                           "Session key (hex, 16-64 bytes): accept only tool messages signed with it, and sign the "
                           "event journal beside --checkpoint with it; default $CUTSIM_SESSION_KEY, else an open "
                           "session")
                ->check(CLI::ExistingFile),
            kRun | kDebrief);
  m.Declare(app.add_option("--auth-window", o.auth_window,
                           "Seconds a signed tool message's timestamp may differ from this host's clock")
                ->check(CLI::Range(0.001, 3600.0)),
            kRealtime);
}

/// Checkpoints and resuming from one.
void AddCheckpointOptions(CLI::App& app, ServerOptions& o, cli::FlagModes& m) {
  m.Declare(app.add_option("--checkpoint", o.checkpoint,
                           "Save the tissue (every cut, positions, velocities) to this file every "
                           "--checkpoint-every s and at a clean exit (SIGINT/SIGTERM); atomic replace"),
            kRun);
  m.Declare(app.add_option("--checkpoint-every", o.checkpoint_every,
                           "Wall seconds between checkpoints (0: only at exit); with --replay --live, recorded "
                           "seconds between the debrief's checkpoints in memory (default 0.25: a seek simulates "
                           "at most that much)")
                ->check(CLI::NonNegativeNumber),
            kRun | kDebrief);
  m.Declare(app.add_flag("--resume", o.resume,
                         "Restore --checkpoint at start when the file exists (a corrupted or foreign file is an "
                         "error)"),
            kRun);
}

/// The message for flags that cannot go together, or null when they can.
const char* OptionConflict(const ServerOptions& o) {
  if (o.resume && o.checkpoint.empty()) return "--resume needs --checkpoint FILE";
  if (o.scene.empty() && o.replay.empty()) return "--scene is required (unless --headless --replay FILE)";
  if (!o.replay.empty() && o.headless == o.live) {
    return o.live ? "--replay takes --headless (check it) or --live (play it to observers), not both"
                  : "--replay needs --headless (check it) or --live (play it to observers)";
  }
  if (o.live && o.replay.empty()) return "--live plays a recording: give --replay FILE";
  if (!o.record.empty() && o.headless) return "--record records a real-time session: drop --headless";
  if (!o.record.empty() && o.resume) {
    return "--record cannot be combined with --resume (a replay starts from the scene)";
  }
  if (o.history.empty() != o.trainee.empty()) return "--history FILE and --trainee NAME go together";
  if (!o.history.empty() && !o.replay.empty()) {
    return "--history appends finished sessions: a --replay re-runs one already recorded";
  }
  return nullptr;
}

}  // namespace

int ServerApp::ParseArgs(int argc, char** argv) {
  CLI::App app{"cutsim-server: owns the tissue FEM model and every cut"};
  cli::FlagModes modes({"a real-time session", "--headless", "--headless --replay", "--replay --live"});
  AddRunOptions(app, options_, modes);
  AddRealtimeOptions(app, options_, modes);
  AddRecordAndAccessOptions(app, options_, modes);
  AddCheckpointOptions(app, options_, modes);
  AddReportOptions(app, options_, modes);
  try {
    app.parse(argc, argv);
  } catch (const CLI::ParseError& e) {
    return app.exit(e);
  }
  options_.session_given = app.count("--session") > 0;
  if (const char* conflict = OptionConflict(options_)) {
    std::fprintf(stderr, "%s\n", conflict);
    return 2;
  }
  // A flag that does nothing in the chosen mode is refused, not ignored.
  const int mode = options_.live                ? kDebriefMode
                   : !options_.replay.empty()   ? kReplayMode
                   : options_.headless          ? kHeadlessMode
                                                : kRealtimeMode;
  if (options_.live) {
    options_.debrief_checkpoint_every = app.count("--checkpoint-every") > 0 ? options_.checkpoint_every : 0.25;
    if (!(options_.debrief_checkpoint_every > 0)) {
      std::fprintf(stderr, "--checkpoint-every: the debrief needs a positive period (recorded seconds)\n");
      return 2;
    }
  }
  if (const std::optional<std::string> refusal = modes.Refusal(app, mode)) {
    std::fprintf(stderr, "%s\n", refusal->c_str());
    return 2;
  }
  if (const std::string why = record::CheckTraineeName(options_.trainee); !options_.trainee.empty() && !why.empty()) {
    std::fprintf(stderr, "--trainee '%s': the name %s\n", options_.trainee.c_str(), why.c_str());
    return 2;
  }
  return -1;
}

int ServerApp::Run() {
  InitLogging("cutsim-server", options_.log_level);
  std::signal(SIGINT, OnSignal);
  std::signal(SIGTERM, OnSignal);
  std::signal(SIGUSR1, OnStatsSignal);
  if (options_.live) return RunDebrief();
  if (!options_.replay.empty()) return RunReplay();
  // Outputs are checked before any work, so a bad path fails now, not after
  // an hour's session.
  for (const auto& [path, what] : {std::pair{&options_.record, "recording (--record)"},
                                   std::pair{&options_.checkpoint, "checkpoint (--checkpoint)"},
                                   std::pair{&options_.stats_json, "statistics (--stats-json)"},
                                   std::pair{&options_.session_report, "session report (--session-report)"},
                                   std::pair{&options_.out, "final state (--out)"}}) {
    if (!path->empty()) CheckOutputPath(*path, what);
  }
  if (!options_.checkpoint.empty()) {
    CheckOutputPath(sim::JournalPathFor(options_.checkpoint).string(), "event journal (beside --checkpoint)");
  }
  if (!options_.session_report.empty()) {
    CheckOutputPath(SessionPlotPath(options_.session_report), "session report's plot (--session-report, .svg)");
  }
  if (options_.resume && !options_.checkpoint.empty() && std::filesystem::exists(options_.checkpoint)) {
    (void)CheckInputFile(options_.checkpoint, "checkpoint (--checkpoint)", sim::kMaxCheckpointBytes);
  }
  if (const auto journal = sim::JournalPathFor(options_.checkpoint);
      options_.resume && !options_.checkpoint.empty() && std::filesystem::exists(journal)) {
    (void)CheckInputFile(journal.string(), "event journal (beside --checkpoint)", sim::kMaxCheckpointBytes);
  }
  if (!options_.history.empty()) (void)CheckHistory(options_.history);
  return options_.headless ? RunHeadless() : RunRealtime();
}

bool WriteOutput(const std::function<void()>& write) {
  try {
    write();
    return true;
  } catch (const std::exception& e) {
    Log().error("output not written: {}", e.what());
    return false;
  }
}

void FillJournalStats(const sim::PeriodicCheckpointer& checkpointer, v1::JournalStats* out) {
  if (!checkpointer.enabled()) return;
  const sim::JournalCounters c = checkpointer.journal_counters();
  using transport::ReportCount;
  out->set_path(checkpointer.journal_path().string());
  out->set_records(ReportCount(c.records));
  out->set_failures(ReportCount(c.failures));
  out->set_restarts(ReportCount(c.restarts));
  out->set_durable_version(ReportCount(c.durable_version));
  out->set_sync_max_ms(1e3 * c.sync_max_seconds);
  out->set_sync_mean_ms(1e3 * c.sync_mean_seconds);
}

bool FinishJournal(sim::PeriodicCheckpointer& checkpointer) {
  if (!checkpointer.enabled()) return true;
  checkpointer.DrainJournal();
  const sim::JournalCounters c = checkpointer.journal_counters();
  if (c.failures == 0) return true;
  Log().error("event journal {} lost {} writes: cuts after the failure were durable only at the next checkpoint",
              checkpointer.journal_path().string(), c.failures);
  return false;
}

std::unique_ptr<transport::HmacJournalSigner> MakeJournalSigner(const ServerOptions& o) {
  if (o.checkpoint.empty()) return nullptr;
  const auto key = transport::LoadSessionKey(o.key_file);
  return key ? std::make_unique<transport::HmacJournalSigner>(*key) : nullptr;
}

std::unique_ptr<transport::HmacToolAuthenticator> MakeToolAuthenticator(const ServerOptions& o) {
  const auto key = transport::LoadSessionKey(o.key_file);
  if (!key) {
    Log().warn("session '{}' is OPEN: no session key (--key-file or ${}), so anyone who can reach "
               "the LCM group can drive the tool. Use a key whenever the session leaves this machine.",
               o.session, transport::kSessionKeyEnv);
    return nullptr;
  }
  Log().info("session '{}': tool messages must be signed (HMAC-SHA256, key from {}, window {} s)",
             o.session, o.key_file.empty() ? std::string("$") + transport::kSessionKeyEnv : o.key_file,
             o.auth_window);
  return std::make_unique<transport::HmacToolAuthenticator>(
      *key, o.session, static_cast<int64_t>(std::llround(o.auth_window * 1e9)));
}

int ServerApp::RunReplay() {
  const ReplayResult r = ReplayRecording(options_.replay, options_.scene);
  const std::string json = transport::ReportJson(MakeReplayReport(options_.replay, r));
  std::printf("%s\n", json.c_str());
  if (!options_.session_report.empty()) {
    WriteSessionReport(options_.session_report, r.report);
    Log().info("wrote the session report {}", options_.session_report);
  }
  if (!r.match) {
    Log().error("replay of {} does NOT match the recording: {}", options_.replay, r.mismatch);
    return 4;
  }
  Log().info("replay of {} matches: {} frames, {} cut frames, {} recorded frame hashes equal, final mesh hash {:016x}",
             options_.replay, r.frames, r.cut_frames, r.hashed_frames, r.mesh_hash);
  if (r.report.status() == sim::kStatusUnconverged) {
    Log().error("the re-run did not converge: {}", r.report.diagnosis());
    return kExitUnconverged;
  }
  return 0;
}

int ServerApp::RunHeadless() {
  const sim::LoadedScene scene = sim::LoadScene(options_.scene);
  auto simulation = sim::Simulation::Create(
      scene, {.threads = options_.threads,
              .precision = options_.precision,
              .integrator = options_.integrator,
              .frame_budget = std::max(0.0, options_.frame_budget) * scene.scene.time_step().frame_dt()});
  const auto signer = MakeJournalSigner(options_);
  sim::PeriodicCheckpointer checkpointer(options_.checkpoint, options_.checkpoint_every, signer.get());
  (void)checkpointer.Begin(*simulation, options_.resume);
  // The run ends at --duration, else when the tool path ends, else (with
  // --until-rest) at rest or --max-time.
  double end_time = options_.max_time;
  if (options_.duration) {
    end_time = *options_.duration;
  } else if (simulation->path_end_time() > 0 && !options_.until_rest) {
    end_time = simulation->path_end_time();  // bounded by the path reader (kMaxSimSeconds)
  } else if (!options_.until_rest) {
    ThrowInputError({.field = "--duration"},
                    "the scene has no tool path: give --duration and/or --until-rest");
  }
  const bool tty = options_.progress && ::isatty(STDERR_FILENO);
  Stopwatch since_report;
  int exit_code = 0;
  while (!StopRequested()) {
    // A remainder below 1 ns is round-off of the frame sum, not a frame: done.
    if (simulation->sim_time() >= end_time - 1e-9) break;
    if (options_.until_rest && simulation->AtRest()) break;
    const double frame = std::min(simulation->frame_dt(), end_time - simulation->sim_time());
    const sim::SimStatus status = simulation->AdvanceFrame(frame);
    if (status != sim::SimStatus::kOk) {
      Log().error("simulation stopped: {}", simulation->Summary().diagnosis);
      exit_code = 3;
      break;
    }
    checkpointer.JournalNewEvents(*simulation);
    checkpointer.MaybeSave(*simulation);
    if (since_report.ElapsedSeconds() > (tty ? 0.2 : 5.0)) {
      since_report.Reset();
      const double frac = std::min(1.0, simulation->sim_time() / end_time);
      const auto s = simulation->QuickSummary();
      if (tty) {
        const int width = 30;
        const int filled = static_cast<int>(frac * width);
        std::fprintf(stderr, "\r[%-*s] %5.1f%%  t=%.4g s  KE=%.3g J  |f|max=%.3g N ", width,
                     std::string(static_cast<size_t>(filled), '#').c_str(), 100.0 * frac,
                     s.sim_time, s.kinetic_energy, s.residual_force);
      } else {
        Log().info("t={:.4g} s ({:.1f}%) KE={:.3g} J residual={:.3g} N", s.sim_time, 100.0 * frac,
                   s.kinetic_energy, s.residual_force);
      }
    }
  }
  if (tty) std::fprintf(stderr, "\n");
  bool outputs_ok = true;
  // Not over a good checkpoint after a blow-up.
  if (exit_code == 0 && checkpointer.enabled() && !checkpointer.Save(*simulation)) outputs_ok = false;
  outputs_ok &= FinishJournal(checkpointer);
  if (options_.until_rest && !simulation->AtRest() && exit_code == 0 && !StopRequested()) {
    Log().warn("did not reach rest within {} s of simulated time", end_time);
  }
  if (!options_.out.empty()) {
    outputs_ok &= WriteOutput([&] {
      simulation->WriteVtu(options_.out);
      Log().info("wrote {}", options_.out);
    });
  }
  if (!options_.session_report.empty()) {
    outputs_ok &= WriteOutput([&] {
      WriteSessionReport(options_.session_report,
                         MakeSessionReport(*simulation, options_.session_given ? options_.session : "headless",
                                           scene.scene.name()));
    });
  }
  if (!options_.history.empty() && exit_code == 0) {
    (void)AppendToHistory(options_.history, options_.trainee, options_.session, scene.scene.name(), *simulation);
  }
  v1::HeadlessSummary summary = HeadlessReport(*simulation);
  FillJournalStats(checkpointer, summary.mutable_journal());
  const std::string json = transport::ReportJson(summary);
  // --stats-json: the same summary, to a file as well.
  if (!options_.stats_json.empty()) {
    outputs_ok &= WriteOutput([&] { WriteFileAtomically(options_.stats_json, json + "\n"); });
  }
  std::printf("%s\n", json.c_str());
  if (std::fflush(stdout) != 0) outputs_ok = false;
  if (exit_code != 0) return exit_code;
  if (!outputs_ok) return kExitOutputFailed;
  if (summary.status() == sim::kStatusUnconverged) {
    Log().error("the run did not converge: {}", summary.diagnosis());
    return kExitUnconverged;
  }
  return 0;
}


bool ClaimSession(transport::ServerPresence& presence, const std::string& session, std::string_view advice) {
  if (const auto peer = presence.Claim()) {
    Log().error("session '{}' is already served by {}: refusing to serve it twice. {}", session, peer->Describe(),
                advice);
    return false;
  }
  presence.Start();
  return true;
}

}  // namespace cutsim::server

#include "server/server_app.h"

#include <unistd.h>

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <csignal>

#include <CLI/CLI.hpp>
#include <fmt/format.h>

#include "common/core/clock.h"
#include "common/core/error.h"
#include "common/core/log.h"
#include "common/sim/checkpoint.h"
#include "common/sim/scene_loader.h"
#include "common/sim/simulation.h"
#include "server/recorder.h"

namespace cutsim::server {
volatile std::sig_atomic_t g_stop = 0;
volatile std::sig_atomic_t g_print_stats = 0;

namespace {

void OnSignal(int) { g_stop = 1; }
void OnStatsSignal(int) { g_print_stats = 1; }

std::string SummaryJson(const sim::SimulationSummary& s) {
  return fmt::format(
      "{{\"scene\": \"{}\", \"precision\": \"{}\", \"nodes\": {}, \"tets\": {}, "
      "\"free_nodes\": {}, \"threads\": {}, \"steps\": {}, \"frames\": {}, \"dt\": {:.9g}, "
      "\"stable_dt\": {:.9g}, \"sim_time\": {:.9g}, \"wall_time\": {:.6g}, "
      "\"tet_steps_per_s\": {:.6g}, \"realtime_factor\": {:.6g}, \"kinetic_energy\": {:.9g}, "
      "\"strain_energy\": {:.9g}, \"residual_force\": {:.9g}, \"max_displacement\": {:.9g}, "
      "\"at_rest\": {}, \"status\": \"{}\", \"diagnosis\": \"{}\", \"cuts\": {}, "
      "\"cut_attempts\": {}, \"cuts_rejected\": {}, \"topology_version\": {}, \"components\": {}, "
      "\"opened_faces\": {}, \"min_rest_volume\": {:.9g}, \"total_mass\": {:.12g}, "
      "\"cut_wall_time\": {:.6g}}}",
      s.scene, s.precision, s.num_nodes, s.num_tets, s.num_free_nodes, s.threads, s.steps,
      s.frames, s.dt, s.stable_dt, s.sim_time, s.wall_time, s.tet_steps_per_s, s.realtime_factor,
      s.kinetic_energy, s.strain_energy, s.residual_force, s.max_displacement,
      s.at_rest ? "true" : "false", s.status, s.diagnosis, s.cuts, s.cut_attempts, s.cuts_rejected,
      s.topology_version, s.components, s.opened_faces, s.min_rest_volume, s.total_mass,
      s.cut_wall_time);
}

}  // namespace

int ServerApp::ParseArgs(int argc, char** argv) {
  CLI::App app{"cutsim-server: owns the tissue FEM model and every cut"};
  app.add_option("--scene", options_.scene,
                 "Scene file (protobuf text format); with --replay, overrides the recorded one")
      ->check(CLI::ExistingFile);
  app.add_flag("--headless", options_.headless,
               "Run as fast as possible with no transport, then print a JSON summary");
  app.add_option("--duration", options_.duration, "Simulated seconds to run")
      ->check(CLI::PositiveNumber);
  app.add_flag("--until-rest", options_.until_rest,
               "Run until kinetic energy and residual force fall below the scene's rest tolerances");
  app.add_option("--max-time", options_.max_time, "Cap on simulated seconds for --until-rest")
      ->check(CLI::PositiveNumber);
  app.add_option("--out", options_.out, "Write the final state to this .vtu file");
  app.add_option("--threads", options_.threads, "Worker threads (0 = scene/all cores)")
      ->check(CLI::NonNegativeNumber);
  app.add_option("--precision", options_.precision, "Override the scene's precision")
      ->check(CLI::IsMember({"float", "double"}));
  app.add_option("--log-level", options_.log_level, "trace, debug, info, warn, error, off");
  app.add_flag("!--no-progress", options_.progress, "No progress bar");
  app.add_option("--session", options_.session, "Session name (LCM channels, DDS key)");
  app.add_option("--lcm-url", options_.lcm_url,
                 "LCM URL of the haptic link (ttl=0 stays on this host; ttl=1 reaches the LAN)");
  app.add_option("--dds-domain", options_.dds_domain, "DDS domain id for the viewers")
      ->check(CLI::Range(0, 230));
  app.add_option("--dds-config", options_.dds_config,
                 "Cyclone DDS configuration file (default: $CYCLONEDDS_URI, else loopback only)")
      ->check(CLI::ExistingFile);
  app.add_flag("!--no-rt", options_.realtime_priority,
               "Keep the physics and LCM threads at normal priority (default: SCHED_FIFO 60/70 when "
               "permitted, below the haptic loop's 80); for a machine shared with normal-priority work, "
               "e.g. a haptic client started with --no-rt");
  app.add_option("--viewer-fps", options_.viewer_fps, "Mesh frames per second to viewers")
      ->check(CLI::Range(0.1, 240.0));
  app.add_option("--frame-rate", options_.frame_rate,
                 "Physics frames (local models) per second; default: the scene's time_step.frame_dt")
      ->check(CLI::Range(1.0, 10000.0));
  app.add_option("--stats-json", options_.stats_json, "Also write the exit statistics to this file");
  app.add_option("--record", options_.record,
                 "Record the session's inputs (tool poses applied, frame times, cuts, final mesh "
                 "hash) to this LCM log");
  app.add_option("--replay", options_.replay,
                 "With --headless: re-run a recording and check its cuts and final mesh hash "
                 "(exit 4 on a mismatch)")
      ->check(CLI::ExistingFile);
  app.add_option("--key-file", options_.key_file,
                 "Session key (hex, 16-64 bytes): accept only tool messages signed with it; "
                 "default $CUTSIM_SESSION_KEY, else an open session")
      ->check(CLI::ExistingFile);
  app.add_option("--auth-window", options_.auth_window,
                 "Seconds a signed tool message's timestamp may differ from this host's clock")
      ->check(CLI::Range(0.001, 3600.0));
  app.add_option("--checkpoint", options_.checkpoint,
                 "Save the tissue (every cut, positions, velocities) to this file every "
                 "--checkpoint-every s and at a clean exit (SIGINT/SIGTERM); atomic replace");
  app.add_option("--checkpoint-every", options_.checkpoint_every,
                 "Wall seconds between checkpoints (0: only at exit)")
      ->check(CLI::NonNegativeNumber);
  app.add_flag("--resume", options_.resume,
               "Restore --checkpoint at start when the file exists (a corrupted or foreign file is an error)");
  try {
    app.parse(argc, argv);
  } catch (const CLI::ParseError& e) {
    return app.exit(e);
  }
  if (options_.resume && options_.checkpoint.empty()) {
    std::fprintf(stderr, "--resume needs --checkpoint FILE\n");
    return 2;
  }
  if (options_.scene.empty() && options_.replay.empty()) {
    std::fprintf(stderr, "--scene is required (unless --headless --replay FILE)\n");
    return 2;
  }
  if (!options_.replay.empty() && !options_.headless) {
    std::fprintf(stderr, "--replay needs --headless\n");
    return 2;
  }
  if (!options_.record.empty() && options_.headless) {
    std::fprintf(stderr, "--record records a real-time session: drop --headless\n");
    return 2;
  }
  if (!options_.record.empty() && options_.resume) {
    // A replay starts from the scene, not from a checkpoint.
    std::fprintf(stderr, "--record cannot be combined with --resume (a replay starts from the scene)\n");
    return 2;
  }
  return -1;
}

int ServerApp::Run() {
  InitLogging("cutsim-server", options_.log_level);
  std::signal(SIGINT, OnSignal);
  std::signal(SIGTERM, OnSignal);
  std::signal(SIGUSR1, OnStatsSignal);
  if (!options_.replay.empty()) return RunReplay();
  return options_.headless ? RunHeadless() : RunRealtime();
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
  const std::string json = fmt::format(
      "{{\"replay\": \"{}\", \"session\": \"{}\", \"scene\": \"{}\", \"match\": {}, \"frames\": {}, "
      "\"cut_frames\": {}, \"cuts\": {}, \"topology_version\": {}, \"sim_time\": {:.9g}, "
      "\"mesh_hash\": \"{:016x}\", \"recorded_mesh_hash\": \"{:016x}\", \"build\": \"{}\"}}",
      options_.replay, r.session, r.scene, r.match ? "true" : "false", r.frames, r.cut_frames, r.cuts,
      r.topology_version, r.sim_time, r.mesh_hash, r.recorded_mesh_hash, BuildClass());
  std::printf("%s\n", json.c_str());
  if (!r.match) {
    Log().error("replay of {} does NOT match the recording: {}", options_.replay, r.mismatch);
    return 4;
  }
  Log().info("replay of {} matches: {} frames, {} cut frames, final mesh hash {:016x}", options_.replay,
             r.frames, r.cut_frames, r.mesh_hash);
  return 0;
}

int ServerApp::RunHeadless() {
  const sim::LoadedScene scene = sim::LoadScene(options_.scene);
  auto simulation = sim::Simulation::Create(
      scene, {.threads = options_.threads, .precision = options_.precision});
  sim::PeriodicCheckpointer checkpointer(options_.checkpoint, options_.checkpoint_every);  // checkpoints
  if (options_.resume) (void)checkpointer.Resume(*simulation);
  // The run ends at --duration, else when the tool path ends, else (with
  // --until-rest) at rest or --max-time.
  double end_time = options_.max_time;
  if (options_.duration) {
    end_time = *options_.duration;
  } else if (simulation->path_end_time() > 0 && !options_.until_rest) {
    end_time = simulation->path_end_time();
  } else if (!options_.until_rest) {
    ThrowInputError({.field = "--duration"},
                    "the scene has no tool path: give --duration and/or --until-rest");
  }
  const bool tty = options_.progress && ::isatty(STDERR_FILENO);
  Stopwatch since_report;
  int exit_code = 0;
  while (!g_stop) {
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
  if (exit_code == 0) (void)checkpointer.Save(*simulation);  // not over a good one after a blow-up
  if (options_.until_rest && !simulation->AtRest() && exit_code == 0 && !g_stop) {
    Log().warn("did not reach rest within {} s of simulated time", end_time);
  }
  if (!options_.out.empty()) {
    simulation->WriteVtu(options_.out);
    Log().info("wrote {}", options_.out);
  }
  std::printf("%s\n", SummaryJson(simulation->Summary()).c_str());
  return exit_code;
}

}  // namespace cutsim::server

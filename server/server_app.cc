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
#include "common/sim/scene_loader.h"
#include "common/sim/simulation.h"

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
  app.add_option("--scene", options_.scene, "Scene file (protobuf text format)")
      ->required()
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
  app.add_option("--viewer-fps", options_.viewer_fps, "Mesh frames per second to viewers")
      ->check(CLI::Range(0.1, 240.0));
  app.add_option("--frame-rate", options_.frame_rate,
                 "Physics frames (local models) per second; default: the scene's time_step.frame_dt")
      ->check(CLI::Range(1.0, 10000.0));
  app.add_option("--stats-json", options_.stats_json, "Also write the exit statistics to this file");
  try {
    app.parse(argc, argv);
  } catch (const CLI::ParseError& e) {
    return app.exit(e);
  }
  return -1;
}

int ServerApp::Run() {
  InitLogging("cutsim-server", options_.log_level);
  std::signal(SIGINT, OnSignal);
  std::signal(SIGTERM, OnSignal);
  std::signal(SIGUSR1, OnStatsSignal);
  return options_.headless ? RunHeadless() : RunRealtime();
}

int ServerApp::RunHeadless() {
  const sim::LoadedScene scene = sim::LoadScene(options_.scene);
  auto simulation = sim::Simulation::Create(
      scene, {.threads = options_.threads, .precision = options_.precision});
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

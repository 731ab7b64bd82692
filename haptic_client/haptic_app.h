#pragma once
/// @file
/// `cutsim-haptic`: the haptic station. A 1 kHz servo loop on absolute
/// deadlines reads the device, sends the tool pose to the server over LCM,
/// renders the newest local model (haptics::HapticRenderer: buffer model, cut
/// decay, watchdog, passivity, force and force-rate limits) and commands the
/// force.
///
/// Real-time design:
/// * Threads: the servo loop (main thread; SCHED_FIFO when permitted), the
///   link's LCM thread (HapticClientLink: sends tool poses, receives models)
///   and a CSV writer thread. The servo loop talks to them only through
///   wait-free single-slot mailboxes (newest wins) and a preallocated
///   single-producer ring of CSV rows; it never blocks, allocates, throws,
///   logs or makes a system call other than clock_gettime, clock_nanosleep
///   and the device's own non-blocking calls (a device plugin's read and
///   force update, docs/devices.md).
/// * Devices: built in (scripted, replay, browser: a trainee's page served
///   on --serve by its own Boost.Beast I/O thread, browser_device.h) or
///   plugins loaded with dlopen
///   (plugin_loader.h, plugin_device.h); every device sits behind
///   DeviceGuard (device_guard.h: workspace mapping, clutch, force clamp,
///   the fade of a lost device).
/// * Pacing: deadline k = t0 + k·period, slept to with clock_nanosleep
///   TIMER_ABSTIME (cutsim::SleepUntilNs), so jitter never accumulates. A tick
///   that wakes after the *next* deadline counts as a missed deadline and the
///   schedule skips ahead (no burst of catch-up ticks: a stale force is worse
///   than one tick of hold).
/// * Memory: mlockall(MCL_CURRENT|MCL_FUTURE) and prefaulted buffers when
///   permitted; with neither CAP_SYS_NICE nor an rtprio limit the loop runs
///   SCHED_OTHER and says so in a warning and in the JSON summary
///   (common/transport/realtime_thread.h does the set-up; servo_loop.h is
///   the loop).
/// * Threads are started before the loop raises its own priority, so the
///   LCM and CSV threads stay SCHED_OTHER.

#include <cstdint>
#include <string>
#include <vector>

#include "common/transport/fault_injection.h"
#include "common/transport/realtime_thread.h"

namespace cutsim::haptic_client {

struct HapticAppOptions {
  std::string session = "default";
  std::string lcm_url = "udpm://239.255.76.67:7667?ttl=0";
  std::string device = "scripted";    ///< scripted | replay | browser | a plugin name or path (plugin_loader.h)
  std::string device_dir;             ///< --device-dir, plugin folder; "" = next to the executable
  std::string device_arg;             ///< --device-arg, passed to the plugin's open
  std::string scene;                  ///< --scene, the device workspace from haptics.device_*
  double workspace_scale = 0.0;       ///< --workspace-scale, 0 = the scene's (else 1)
  std::vector<double> workspace_offset;  ///< --workspace-offset x y z, m; empty = the scene's (else 0)
  int clutch_button = 1;              ///< --clutch-button, bit index; -1 = no clutch
  double unplug_fade = 0.05;          ///< s, force ramp to zero when the device is lost
  std::string path;                   ///< --path, tool path for `scripted`
  std::string log;                    ///< --log, LCM log for `replay`
  std::string log_channel;            ///< --log-channel, default CUTSIM_<session>_TOOL
  double rate = 1000.0;               ///< Hz, servo rate
  double tool_rate = 1000.0;          ///< Hz, tool pose publishing rate (≤ rate)
  std::string csv = "out/haptic.csv"; ///< "" or "-" = no CSV
  double duration = 0.0;              ///< s, 0 = until the device is done (or a signal)
  double max_force = 0.0;             ///< N, 0 = the device's
  double max_stiffness = 0.0;         ///< N/m, 0 = the device's
  double max_force_rate = 0.0;        ///< N/s, 0 = renderer default
  double decay_per_second = 0.0;      ///< ξ, 1/s, used when the model sends 0; 0 = default
  double watchdog = 0.0;              ///< s, 0 = default (50 ms + 50 ms fade)
  bool passivity = true;              ///< --no-passivity turns the PC off (observer stays)
  transport::FaultConfig faults;      ///< --fault-*
  std::string fault_direction = "both";  ///< both | tool | model
  bool realtime = true;               ///< --no-rt: do not try SCHED_FIFO / mlockall
  int rt_priority = transport::kHapticLoopPriority;  ///< --rt-priority, SCHED_FIFO 1..99
  std::string serve = "127.0.0.1:0"; ///< --serve ADDRESS:PORT, the trainee page of `browser`
  std::string page_dir;               ///< --page-dir, the trainee page's files; "" = the source tree's web/trainee
  std::string url_file;               ///< --url-file, where the page's URL (with its token) is written, mode 0600
  std::vector<std::string> host_names;  ///< --host-name, further names the trainee page may be opened at
  uint32_t dds_domain = 0;            ///< --dds-domain, the mesh stream the trainee page draws
  std::string dds_config;             ///< --dds-config, Cyclone configuration file
  bool page_view = true;              ///< --no-page-view: the trainee page draws no tissue (no DDS reader)
  std::string key_file;               ///< --key-file: hex session key; "" = $CUTSIM_SESSION_KEY, else unsigned
};

/// Validates the options (throws `InputError` naming the flag).
void ValidateOptions(const HapticAppOptions& options);

/// Runs the station until the device is done, `duration` passes, or
/// SIGINT/SIGTERM. Logs the stats and prints one JSON line on stdout.
/// Returns the process exit code (0 on a normal end).
int RunHapticApp(const HapticAppOptions& options);

}  // namespace cutsim::haptic_client

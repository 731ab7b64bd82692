// cutsim-haptic: the haptic station (see haptic_app.h).
#include <cstdio>
#include <exception>
#include <optional>
#include <string>

#include <CLI/CLI.hpp>

#include "common/cli/flag_modes.h"
#include "common/core/error.h"
#include "common/core/log.h"
#include "common/transport/fault_flags.h"
#include "haptic_client/haptic_app.h"

int main(int argc, char** argv) {
  using cutsim::haptic_client::HapticAppOptions;
  HapticAppOptions o;
  std::string log_level = "info";
  bool no_rt = false;
  bool no_passivity = false;
  bool no_page_view = false;
  CLI::App app{"cutsim-haptic: 1 kHz haptic station (scripted, replayed, browser or plugin device) over LCM"};
  // The device kinds, each a mode of the station's flags.
  cutsim::cli::FlagModes modes({"--device scripted", "--device replay", "--device browser", "a device plugin"});
  constexpr cutsim::cli::ModeSet kScripted = 1U << 0, kReplay = 1U << 1, kBrowser = 1U << 2, kPlugin = 1U << 3;
  app.add_option("--session", o.session, "Session name")->capture_default_str();
  app.add_option("--lcm-url", o.lcm_url, "LCM URL (ttl=1 to reach another machine)")->capture_default_str();
  app.add_option("--device", o.device,
                 "scripted | replay | browser | NAME (plugin libcutsim_device_NAME.so in --device-dir) | PATH to a plugin")
      ->capture_default_str();
  modes.Declare(app.add_option("--device-dir", o.device_dir,
                               "Folder of device plugins (default: the installed lib/<multiarch>/cutsim/devices, "
                               "else next to cutsim-haptic)"),
                kPlugin);
  modes.Declare(app.add_option("--device-arg", o.device_arg, "Configuration string passed to the device plugin's open"),
                kPlugin);
  app.add_option("--scene", o.scene, "Scene whose haptics.device_scale/device_offset map the device to the tissue")
      ->check(CLI::ExistingFile);
  app.add_option("--workspace-scale", o.workspace_scale, "Tissue metres per device metre (0 = the scene's, else 1)")
      ->capture_default_str();
  app.add_option("--workspace-offset", o.workspace_offset, "Tissue position of the device origin x y z, m")
      ->expected(3);
  app.add_option("--clutch-button", o.clutch_button, "Button bit of the clutch (-1 = none)")->capture_default_str();
  app.add_option("--unplug-fade", o.unplug_fade, "Force ramp to zero when the device is lost, s")
      ->capture_default_str();
  modes.Declare(
      app.add_option("--serve", o.serve, "Trainee page of --device browser: ADDRESS:PORT (loopback by default)")
          ->capture_default_str(),
      kBrowser);
  modes.Declare(
      app.add_option("--page-dir", o.page_dir, "The trainee page's files (default: web/trainee in the installed data folder, "
                                  "share/cutsim beside bin/, else in the source tree)"),
      kBrowser);
  modes.Declare(app.add_option("--url-file", o.url_file,
                               "Write the trainee page's URL (it carries the session's token) to this file, mode "
                               "0600, instead of stdout"),
                kBrowser);
  modes.Declare(app.add_option("--host-name", o.host_names,
                               "A further name the trainee page may be opened at (the Host and Origin it accepts; "
                               "repeat for more)"),
                kBrowser);
  modes.Declare(app.add_option("--dds-domain", o.dds_domain, "DDS domain of the mesh stream the trainee page draws")
                    ->capture_default_str(),
                kBrowser);
  modes.Declare(
      app.add_option("--dds-config", o.dds_config, "Cyclone DDS configuration file for the trainee page's mesh stream"),
      kBrowser);
  modes.Declare(app.add_flag("--no-page-view", no_page_view, "The trainee page draws no tissue (reads no mesh stream)"),
                kBrowser);
  modes.Declare(app.add_option("--path", o.path, "Tool path file for --device scripted (minimum-jerk timing)"),
                kScripted);
  modes.Declare(app.add_option("--log", o.log, "LCM log (lcm-logger or server recorder) for --device replay"),
                kReplay);
  modes.Declare(app.add_option("--log-channel", o.log_channel, "Channel to replay (default CUTSIM_<session>_TOOL)"),
                kReplay);
  app.add_option("--rate", o.rate, "Servo loop rate, Hz")->capture_default_str();
  app.add_option("--tool-rate", o.tool_rate, "Tool pose publishing rate, Hz (≤ --rate)")->capture_default_str();
  app.add_option("--csv", o.csv, "CSV of force, model age and loop timing (\"-\" = none)")->capture_default_str();
  app.add_option("--duration", o.duration, "Stop after this many seconds (0 = when the device is done)")
      ->capture_default_str();
  app.add_option("--max-force", o.max_force, "Force limit, N (0 = the device's)")->capture_default_str();
  app.add_option("--max-stiffness", o.max_stiffness, "Stiffness limit, N/m (0 = the device's)")->capture_default_str();
  app.add_option("--max-force-rate", o.max_force_rate, "Force-rate limit, N/s (0 = default 2000)")->capture_default_str();
  app.add_option("--decay-per-second", o.decay_per_second,
                 "Cut-force decay ξ, 1/s, when the model sends none (0 = default 30)")->capture_default_str();
  app.add_option("--watchdog", o.watchdog, "Seconds without a model before the fade (0 = default 0.05)")
      ->capture_default_str();
  app.add_flag("--no-passivity", no_passivity, "Turn the passivity controller off (the observer still reports)");
  cutsim::transport::AddFaultFlags(app, &o.faults);
  app.add_option("--fault-direction", o.fault_direction, "Where faults apply: both | tool | model")
      ->group("Fault injection")->capture_default_str();
  app.add_option("--key-file", o.key_file,
                 "Session key (hex, 16-64 bytes) to sign tool messages; default $CUTSIM_SESSION_KEY")
      ->check(CLI::ExistingFile);
  app.add_flag("--no-rt", no_rt, "Do not try SCHED_FIFO and mlockall");
  app.add_option("--rt-priority", o.rt_priority, "SCHED_FIFO priority of the servo loop")->capture_default_str();
  app.add_option("--log-level", log_level, "trace, debug, info, warn, error, off")->capture_default_str();
  // Every other flag acts with every device.
  modes.DeclareRest(app, modes.all());
  CLI11_PARSE(app, argc, argv);
  // A flag that does nothing with the chosen device is refused, not ignored.
  const int mode = o.device == "scripted" ? 0 : o.device == "replay" ? 1 : o.device == "browser" ? 2 : 3;
  if (const std::optional<std::string> refusal = modes.Refusal(app, mode)) {
    std::fprintf(stderr, "%s\n", refusal->c_str());
    return 2;
  }
  o.realtime = !no_rt;
  o.passivity = !no_passivity;
  o.page_view = !no_page_view;
  try {
    cutsim::InitLogging("cutsim-haptic", log_level);
    return cutsim::haptic_client::RunHapticApp(o);
  } catch (const cutsim::InputError& e) {
    cutsim::Log().error("{}", e.what());
    return 2;
  } catch (const std::exception& e) {
    cutsim::Log().error("fatal: {}", e.what());
    return 1;
  }
}

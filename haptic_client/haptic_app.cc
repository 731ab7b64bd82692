#include "haptic_client/haptic_app.h"

#include <algorithm>
#include <atomic>
#include <cmath>
#include <csignal>
#include <cstdio>
#include <filesystem>
#include <memory>
#include <string>
#include <tuple>
#include <utility>

#include <fmt/format.h>

#include "common/core/error.h"
#include "common/core/install_paths.h"
#include "common/core/log.h"
#include "common/haptics/haptic_renderer.h"
#include "common/haptics/tool_path.h"
#include "common/transport/channels.h"
#include "common/transport/haptic_link.h"
#include "common/transport/lcm_bus.h"
#include "common/transport/lcm_packet.h"
#include "common/transport/stream_auth.h"
#include "common/transport/realtime_thread.h"
#include "common/transport/report_json.h"
#include "common/transport/tool_auth.h"
#include "common/web/trainee_server.h"
#include "cutsim/v1/report.pb.h"
#include "haptic_client/browser_device.h"
#include "haptic_client/device_guard.h"
#include "haptic_client/plugin_device.h"
#include "haptic_client/plugin_loader.h"
#include "haptic_client/scene_haptics.h"
#include "haptic_client/servo_loop.h"
#include "haptic_client/threaded_device.h"
#include "haptic_client/virtual_devices.h"

namespace cutsim::haptic_client {

/// Exit status of a run that never received a model from a server.
constexpr int kExitNoModel = 3;
/// Exit status of a run that ended because the device stopped answering.
constexpr int kExitDeviceStuck = 4;
/// A plugin's reading older than this is late (the guard holds the tool
/// and fades the force), s; one this old says the device is stuck.
constexpr double kDeviceLateSeconds = 0.003;
constexpr double kDeviceStuckSeconds = 1.0;

namespace {

using transport::ReportCount;

std::atomic<bool> g_stop{false};
extern "C" void OnStopSignal(int /*sig*/) { g_stop.store(true); }

/// `--serve ADDRESS:PORT` split ("[::1]:8090" for IPv6).
std::pair<std::string, uint16_t> SplitServe(const std::string& serve) {
  const size_t colon = serve.rfind(':');
  int port = -1;
  if (colon != std::string::npos) {
    try {
      size_t used = 0;
      port = std::stoi(serve.substr(colon + 1), &used);
      if (used != serve.size() - colon - 1) port = -1;
    } catch (const std::exception&) {
      port = -1;
    }
  }
  if (port < 0 || port > 65535) {
    ThrowInputError(SourceRef{.field = "--serve"}, fmt::format("\"{}\": use ADDRESS:PORT, port 0..65535", serve));
  }
  std::string address = serve.substr(0, colon);
  if (address.size() > 2 && address.front() == '[' && address.back() == ']') address = address.substr(1, address.size() - 2);
  return {address, static_cast<uint16_t>(port)};
}

GuardOptions MakeGuardOptions(const HapticAppOptions& o);

/// The browser device: the trainee page on --serve, its token from the
/// session key, its 3-D view from the session's mesh stream and the scene.
std::unique_ptr<HapticDevice> MakeBrowserDevice(const HapticAppOptions& o) {
  const auto key = transport::LoadSessionKey(o.key_file);
  if (!key) {
    ThrowInputError(SourceRef{.field = "--key-file"},
                    fmt::format("--device browser needs the session key (--key-file or ${}): the trainee page's "
                                "token is derived from it",
                                transport::kSessionKeyEnv));
  }
  BrowserDeviceOptions bo;
  std::tie(bo.address, bo.port) = SplitServe(o.serve);
  bo.token = TraineeToken(*key);
  bo.page_dir = o.page_dir.empty() ? (DataDir() / "web" / "trainee").string() : o.page_dir;
  bo.url_file = o.url_file;
  bo.host_names = o.host_names;
  const GuardOptions mapping = MakeGuardOptions(o);
  bo.world_scale = mapping.scale;
  bo.world_offset = mapping.offset;
  if (!o.scene.empty()) {
    const SceneWorkspace w = ReadSceneWorkspace(o.scene);
    bo.planned_incision = w.planned_incision;
    if (w.blade_length > 0.0) bo.blade_length = w.blade_length;
  }
  if (o.page_view) bo.view = TraineeViewOptions{o.session, o.dds_domain, o.dds_config, key};
  auto device = std::make_unique<BrowserDevice>(bo, BrowserDevice::DefaultInfo());
  const DeviceInfo& d = device->info();
  Log().info("browser device: trainee page on {} (the token is in the URL{}; workspace [{:.3f}, {:.3f}] x [{:.3f}, "
             "{:.3f}] x [{:.3f}, {:.3f}] m)",
             device->server().BaseUrl(), o.url_file.empty() ? " printed on stdout" : " written to --url-file",
             d.workspace_min.x(), d.workspace_max.x(), d.workspace_min.y(), d.workspace_max.y(), d.workspace_min.z(),
             d.workspace_max.z());
  if (o.url_file.empty()) {
    std::printf("trainee: %s\n", device->url().c_str());
    std::fflush(stdout);
  }
  return device;
}

std::unique_ptr<HapticDevice> MakeDevice(const HapticAppOptions& o) {
  if (o.device == "browser") return MakeBrowserDevice(o);
  DeviceInfo info;
  if (o.device == "scripted") {
    info.name = "scripted";
    return std::make_unique<ScriptedDevice>(haptics::ToolPath::Read(o.path), info);
  }
  if (o.device == "replay") {
    info.name = "replay";
    const std::string channel =
        o.log_channel.empty() ? transport::LcmChannelName(o.session, transport::LcmChannel::kTool) : o.log_channel;
    return std::make_unique<ReplayDevice>(o.log, channel, info);
  }
  const std::filesystem::path dir = o.device_dir.empty() ? PluginDir() : std::filesystem::path(o.device_dir);
  const std::filesystem::path path = ResolvePluginPath(o.device, dir);
  std::error_code ec;
  if (!std::filesystem::exists(path, ec)) {
    ThrowInputError(SourceRef{.file = path.string(), .field = "--device"},
                    fmt::format("unknown device \"{}\": not built in (scripted, replay) and no device plugin here "
                                "(--device-dir picks the folder; --device PATH loads a plugin file)",
                                o.device));
  }
  auto plugin = std::make_unique<PluginDevice>(PluginLibrary::Load(path), o.device_arg);
  // The plugin's calls may block: they run on a thread of their own, and
  // the loop only takes their newest reading (threaded_device.h).
  ThreadedDeviceOptions deadline;
  deadline.late_ticks = std::max<int64_t>(2, std::llround(kDeviceLateSeconds * o.rate));
  deadline.stuck_ticks = std::max<int64_t>(deadline.late_ticks + 1, std::llround(kDeviceStuckSeconds * o.rate));
  auto device = std::make_unique<ThreadedDevice>(std::move(plugin), deadline);
  const DeviceInfo& d = device->info();
  Log().info("device plugin {} ({}): workspace [{:.3f}, {:.3f}] x [{:.3f}, {:.3f}] x [{:.3f}, {:.3f}] m, max force "
             "{} N{}, max stiffness {} N/m, rate {} Hz",
             d.name, path.string(), d.workspace_min.x(), d.workspace_max.x(), d.workspace_min.y(),
             d.workspace_max.y(), d.workspace_min.z(), d.workspace_max.z(), d.max_force,
             d.max_force > 0.0 ? "" : " (input only: the force is rendered and recorded, not sent)", d.max_stiffness,
             d.rate_hz);
  if (d.rate_hz > 0.0 && d.rate_hz < o.rate) {
    Log().warn("device {} updates at {} Hz, below the {} Hz loop: the loop holds its last reading between updates",
               d.name, d.rate_hz, o.rate);
  }
  return device;
}

/// The workspace mapping and safety settings: the scene's, overridden by
/// the command line.
GuardOptions MakeGuardOptions(const HapticAppOptions& o) {
  GuardOptions g;
  if (!o.scene.empty()) {
    const SceneWorkspace w = ReadSceneWorkspace(o.scene);
    g.scale = w.scale;
    g.offset = w.offset;
  }
  if (o.workspace_scale > 0.0) g.scale = o.workspace_scale;
  if (o.workspace_offset.size() == 3) g.offset = {o.workspace_offset[0], o.workspace_offset[1], o.workspace_offset[2]};
  g.clutch_mask = o.clutch_button < 0 ? 0U : (1U << o.clutch_button);
  g.fade_s = o.unplug_fade;
  return g;
}

haptics::RendererConfig MakeConfig(const HapticAppOptions& o, const DeviceInfo& info) {
  haptics::HapticParamsView params;
  params.decay_per_second = o.decay_per_second;
  params.watchdog = o.watchdog;
  params.max_force = o.max_force > 0.0 ? std::min(o.max_force, info.max_force) : info.max_force;
  params.max_stiffness = o.max_stiffness > 0.0 ? std::min(o.max_stiffness, info.max_stiffness) : info.max_stiffness;
  haptics::RendererConfig config = haptics::MakeRendererConfig(params, "cutsim-haptic");
  config.device.max_damping = std::min(config.device.max_damping, info.max_damping);
  if (o.max_force_rate > 0.0) config.device.max_force_rate = o.max_force_rate;
  config.passivity.enabled = o.passivity;
  config.passivity.force_rate = config.device.max_force_rate;
  haptics::ValidateConfig(config, "cutsim-haptic");
  return config;
}

/// The session key's two uses on the station: signing tool messages and
/// checking the server's models. Both null (an open session, with a
/// warning) when there is no key.
struct StationAuth {
  std::unique_ptr<transport::HmacToolAuthenticator> tools;
  std::unique_ptr<transport::PayloadAuthenticator> models;
};

StationAuth MakeAuthenticators(const HapticAppOptions& o) {
  const auto key = transport::LoadSessionKey(o.key_file);
  if (!key) {
    Log().warn("session '{}' is OPEN: no session key (--key-file or ${}): tool messages are NOT signed (a server "
               "with a key ignores them) and models are NOT authenticated (anyone on the LCM group can set the "
               "device's force)",
               o.session, transport::kSessionKeyEnv);
    return {};
  }
  Log().info("session '{}': tool messages are signed and models must be signed (HMAC-SHA256, key from {}, "
             "models within 2 s of this clock)",
             o.session, o.key_file.empty() ? std::string("$") + transport::kSessionKeyEnv : o.key_file);
  return {std::make_unique<transport::HmacToolAuthenticator>(*key, o.session),
          std::make_unique<transport::PayloadAuthenticator>(*key, transport::kHapticModelDomain, o.session)};
}

/// Fault injection per direction and the authenticators.
transport::HapticLinkOptions MakeLinkOptions(const HapticAppOptions& o, const StationAuth& auth,
                                             const haptics::RendererConfig& config) {
  transport::HapticLinkOptions link_options;
  if (o.fault_direction != "model") link_options.publish_faults = o.faults;
  if (o.fault_direction != "tool") {
    link_options.receive_faults = o.faults;
    link_options.receive_faults.seed = o.faults.seed + 1;  // independent fates per direction
  }
  if (o.faults.active()) Log().info("fault injection ({}): {}", o.fault_direction, transport::Describe(o.faults));
  link_options.authenticator = auth.tools.get();
  link_options.model_auth = auth.models.get();
  // Refused models are explained once the watchdog has noticed the silence.
  link_options.silence_ns = static_cast<int64_t>(config.watchdog * 1e9);
  return link_options;
}

void LogSummary(const char* end_reason, const ServoLoop& loop, const haptics::RendererStats& rs,
                const transport::HapticClientLinkStats& ls) {
  const LoopTiming& t = loop.timing();
  Log().info("haptic loop ended ({}): {} ticks, {} missed deadlines, period p50 {:.1f} µs p99 {:.1f} µs max "
             "{:.1f} µs, jitter p99 {:.1f} µs",
             end_reason, loop.ticks(), loop.missed_deadlines(), t.period_us.Quantile(0.5),
             t.period_us.Quantile(0.99), t.period_us.max(), t.jitter_us.Quantile(0.99));
  Log().info("models: {} accepted, {} rejected, {} stale by the renderer; link: {} received, {} garbage, {} "
             "foreign session, {} out of order, {} duplicate, {} malformed, {} server restarts",
             rs.models_accepted, rs.models_rejected, rs.models_stale, ls.models_received, ls.decode_errors,
             ls.foreign_session, ls.stale, ls.duplicate, ls.malformed, ls.restarts);
  const transport::PacketCounts& p = ls.packets;
  using R = transport::PacketReason;
  Log().info("model packets{}: {} accepted, {} superseded, {} garbage, {} fragments, {} other channels, {} "
             "oversized, {} undecodable, {} foreign, {} unsigned, {} forged, {} replayed, {} outside the window, {} "
             "invalid epoch, {} from another server, {} invalid, {} stale; {} dropped by the kernel",
             p.packet_level ? "" : " (per LCM delivery)", p[R::kAccepted], p[R::kSuperseded], p[R::kNotLcm],
             p[R::kFragment], p[R::kOtherChannel], p[R::kOversized], p[R::kDecodeError], p[R::kForeignSession],
             p[R::kUnsigned], p[R::kForged], p[R::kReplayed], p[R::kOutsideWindow], p[R::kInvalidEpoch],
             p[R::kOtherSender], p[R::kInvalid], p[R::kStale], p.kernel_dropped);
  Log().info("watchdog trips {}, cut decays {}, passivity dissipated {:.6f} J (E_obs {:.6f} J, min {:.6f} J), "
             "model age p99 {:.2f} ms, pose-to-model p99 {:.2f} ms",
             rs.watchdog_trips, rs.cut_decays_started, rs.passivity_dissipated, rs.observed_energy,
             rs.min_observed_energy, t.model_age_ms.Quantile(0.99), t.pose_to_model_ms.Quantile(0.99));
  if (loop.csv_dropped() > 0) Log().warn("{} CSV rows dropped (writer too slow)", loop.csv_dropped());
}

v1::HapticLinkReport LinkReport(const transport::HapticClientLinkStats& ls) {
  v1::HapticLinkReport r;
  r.set_tools_written(ReportCount(ls.tools_written));
  r.set_tools_published(ReportCount(ls.tools_published));
  r.set_tools_coalesced(ReportCount(ls.tools_coalesced));
  r.set_tools_not_sent(ReportCount(ls.tools_not_sent));
  r.set_models_received(ReportCount(ls.models_received));
  r.set_models_superseded(ReportCount(ls.models_superseded));
  r.set_decode_errors(ReportCount(ls.decode_errors));
  r.set_foreign_session(ReportCount(ls.foreign_session));
  r.set_stale(ReportCount(ls.stale));
  r.set_duplicate(ReportCount(ls.duplicate));
  r.set_malformed(ReportCount(ls.malformed));
  r.set_restarts(ReportCount(ls.restarts));
  r.set_accepted(ReportCount(ls.accepted));
  transport::ToReport(ls.packets, r.mutable_model_packets());
  r.set_models_missed(ReportCount(ls.missed));
  return r;
}

v1::HapticFaultReport FaultReport(const transport::FaultStats& tool, const transport::FaultStats& model) {
  v1::HapticFaultReport r;
  r.set_tool_dropped(ReportCount(tool.dropped));
  r.set_tool_duplicated(ReportCount(tool.duplicated));
  r.set_model_dropped(ReportCount(model.dropped));
  r.set_model_duplicated(ReportCount(model.duplicated));
  r.set_model_reordered(ReportCount(model.reordered));
  return r;
}

/// What happened to the device during the run.
struct DeviceOutcome {
  std::string name;
  bool lost = false;
  double lost_at_s = 0.0;
  uint64_t clutch_engagements = 0;
  uint64_t forces_clamped = 0;
  uint64_t read_errors = 0;
  // A plugin on its own thread (threaded_device.h).
  uint64_t late_ticks = 0;
  uint64_t late_episodes = 0;
  double max_lag_ms = 0.0;
  bool stuck = false;
};

struct RunOutcome {
  const char* end_reason;
  transport::RealtimeStatus realtime;
  uint64_t csv_rows;
  DeviceOutcome device;
};

/// Collects the guard's and the plugin's counters and logs a lost device.
DeviceOutcome SummariseDevice(const HapticDevice& device, const DeviceGuard& guard, int64_t loop_start_ns,
                              const GuardOptions& options, double rate_hz) {
  DeviceOutcome d;
  d.name = device.info().name;
  const GuardStats& gs = guard.stats();
  d.lost = gs.lost;
  d.lost_at_s = gs.lost ? 1e-9 * static_cast<double>(gs.lost_ns - loop_start_ns) : 0.0;
  d.clutch_engagements = gs.clutch_engagements;
  d.forces_clamped = gs.force_clamped;
  std::string why;
  if (const auto* threaded = dynamic_cast<const ThreadedDevice*>(&device)) {
    const ThreadedDeviceStats ts = threaded->stats();
    d.late_ticks = ts.late_ticks;
    d.late_episodes = ts.late_episodes;
    d.max_lag_ms = 1e3 * static_cast<double>(ts.max_lag_ticks) / rate_hz;
    d.stuck = ts.stuck;
    // A device left to its thread may still be inside the plugin: its
    // counters are not ours to read.
    const auto* plugin = dynamic_cast<const PluginDevice*>(&threaded->device());
    if (plugin != nullptr && !ts.abandoned) {
      d.read_errors = plugin->stats().read_errors + plugin->stats().bad_poses;
      why = plugin->last_error();
    }
    if (d.late_ticks > 0) {
      Log().warn("device {}: its readings were late on {} ticks in {} runs (at most {:.1f} ms behind): the tool held "
                 "and the force faded to zero each time",
                 d.name, d.late_ticks, d.late_episodes, d.max_lag_ms);
    }
  }
  if (d.lost) {
    Log().warn("device {} was lost {:.3f} s into the loop ({}); the force faded to zero over {:.0f} ms and the tool "
               "held its last pose for the rest of the session",
               d.name, d.lost_at_s, why.empty() ? "read failed" : why, 1e3 * options.fade_s);
  }
  if (const auto* browser = dynamic_cast<const BrowserDevice*>(&device)) {
    const BrowserDeviceStats bs = browser->stats();
    const web::TraineeServerStats ss = browser->server().stats();
    const auto& r = bs.refused;
    auto n = [&r](SampleError e) { return r[static_cast<size_t>(e)]; };
    Log().info("browser device: {} pages connected, {} samples, {} heartbeats, {} clock restarts; refused: {} "
               "malformed, {} not finite, {} out of range, {} bad direction, {} bad buttons, {} time going back, {} "
               "off the stream's clock; {} over the rate cap, {} oversized, {} idle; upgrades refused: {} token, {} "
               "origin, {} host, {} key, {} busy; {} connections refused at accept; {} frames sent",
               bs.connections, bs.samples, bs.heartbeats, bs.reanchors, n(SampleError::kFormat),
               n(SampleError::kNotFinite), n(SampleError::kRange), n(SampleError::kDirection),
               n(SampleError::kButtons), n(SampleError::kTimeBackwards), n(SampleError::kClock), ss.rate_limited,
               ss.closed_oversized, ss.closed_idle, ss.web.refused_token, ss.web.refused_origin, ss.web.refused_host,
               ss.web.refused_key, ss.web.refused_cap, ss.web.refused_connections, ss.frames_sent);
    d.read_errors = bs.refused_total();
  }
  if (d.read_errors > 0) Log().warn("device {}: {} failed or invalid reads (the last pose was held)", d.name, d.read_errors);
  return d;
}

v1::HapticStats StatsReport(const HapticAppOptions& o, const RunOutcome& run, const ServoLoop& loop,
                            const haptics::RendererStats& rs, const transport::HapticClientLink& link) {
  const LoopTiming& t = loop.timing();
  v1::HapticStats r;
  r.set_kind("haptic_stats");
  r.set_end(run.end_reason);
  r.set_ticks(ReportCount(loop.ticks()));
  r.set_missed_deadlines(ReportCount(loop.missed_deadlines()));
  r.set_rate_hz(o.rate);
  r.set_sched_fifo(run.realtime.fifo);
  r.set_mlocked(run.realtime.mlocked);
  *r.mutable_period_us() = QuantilesReport(t.period_us);
  *r.mutable_jitter_us() = QuantilesReport(t.jitter_us);
  *r.mutable_lateness_us() = QuantilesReport(t.lateness_us);
  *r.mutable_model_age_ms() = QuantilesReport(t.model_age_ms);
  *r.mutable_pose_to_model_ms() = QuantilesReport(t.pose_to_model_ms);
  *r.mutable_pose_to_use_ms() = QuantilesReport(t.pose_to_use_ms);
  r.set_models_accepted(ReportCount(rs.models_accepted));
  r.set_models_rejected(ReportCount(rs.models_rejected));
  r.set_models_stale(ReportCount(rs.models_stale));
  r.set_watchdog_trips(ReportCount(rs.watchdog_trips));
  r.set_cut_decays(ReportCount(rs.cut_decays_started));
  r.set_non_finite_inputs(ReportCount(rs.non_finite_inputs));
  r.set_passivity_dissipated_j(rs.passivity_dissipated);
  r.set_observed_energy_j(rs.observed_energy);
  r.set_min_observed_energy_j(rs.min_observed_energy);
  r.set_max_force_n(rs.max_force);
  r.set_max_force_step_n(rs.max_force_step);
  *r.mutable_link() = LinkReport(link.stats());
  r.mutable_link()->set_models_authenticated(link.authenticates_models());
  *r.mutable_faults() = FaultReport(link.publish_fault_stats(), link.receive_fault_stats());
  r.set_csv_rows(ReportCount(run.csv_rows));
  r.set_csv_dropped(ReportCount(loop.csv_dropped()));
  r.set_device(run.device.name);
  r.set_device_lost(run.device.lost);
  r.set_device_lost_at_s(run.device.lost_at_s);
  r.set_clutch_engagements(ReportCount(run.device.clutch_engagements));
  r.set_forces_clamped(ReportCount(run.device.forces_clamped));
  r.set_device_read_errors(ReportCount(run.device.read_errors));
  r.set_device_late_ticks(ReportCount(run.device.late_ticks));
  r.set_device_late_episodes(ReportCount(run.device.late_episodes));
  r.set_device_max_lag_ms(run.device.max_lag_ms);
  r.set_device_stuck(run.device.stuck);
  return r;
}

}  // namespace

void ValidateOptions(const HapticAppOptions& o) {
  transport::ValidateSessionName(o.session, "--session");
  if (o.device.empty()) {
    ThrowInputError(SourceRef{.field = "--device"}, "empty (scripted, replay, or a device plugin's name or path)");
  }
  if (o.device == "scripted" && o.path.empty()) ThrowInputError(SourceRef{.field = "--path"}, "--device scripted needs --path FILE");
  if (o.device == "replay" && o.log.empty()) ThrowInputError(SourceRef{.field = "--log"}, "--device replay needs --log FILE");
  if (!(o.rate >= 50.0 && o.rate <= 20000.0)) ThrowInputError(SourceRef{.field = "--rate"}, fmt::format("{} Hz is out of range (50 to 20000)", o.rate));
  if (!(o.tool_rate > 0.0 && o.tool_rate <= o.rate)) {
    ThrowInputError(SourceRef{.field = "--tool-rate"}, fmt::format("{} Hz is out of range (0 < rate ≤ --rate)", o.tool_rate));
  }
  auto non_negative = [](double v, const char* flag) {
    if (!(std::isfinite(v) && v >= 0.0)) ThrowInputError(SourceRef{.field = flag}, fmt::format("{} must be ≥ 0", v));
  };
  non_negative(o.duration, "--duration");
  non_negative(o.max_force, "--max-force");
  non_negative(o.max_stiffness, "--max-stiffness");
  non_negative(o.max_force_rate, "--max-force-rate");
  non_negative(o.decay_per_second, "--decay-per-second");
  non_negative(o.watchdog, "--watchdog");
  transport::ValidateFaultConfig(o.faults, "--fault-");
  if (o.fault_direction != "both" && o.fault_direction != "tool" && o.fault_direction != "model") {
    ThrowInputError(SourceRef{.field = "--fault-direction"}, fmt::format("\"{}\": use both, tool or model", o.fault_direction));
  }
  if (o.rt_priority < 1 || o.rt_priority > 99) ThrowInputError(SourceRef{.field = "--rt-priority"}, "use 1 to 99");
  if (!(std::isfinite(o.workspace_scale) && o.workspace_scale >= 0.0 && o.workspace_scale <= 1e3)) {
    ThrowInputError(SourceRef{.field = "--workspace-scale"},
                    fmt::format("{} is out of range [0, 1000] (0 = the scene's)", o.workspace_scale));
  }
  if (!o.workspace_offset.empty() &&
      (o.workspace_offset.size() != 3 ||
       !std::all_of(o.workspace_offset.begin(), o.workspace_offset.end(), [](double v) { return std::isfinite(v); }))) {
    ThrowInputError(SourceRef{.field = "--workspace-offset"}, "needs three finite numbers x y z (m)");
  }
  if (o.clutch_button < -1 || o.clutch_button > 31) {
    ThrowInputError(SourceRef{.field = "--clutch-button"}, fmt::format("{}: use a bit 0..31, or -1 for none", o.clutch_button));
  }
  if (!(std::isfinite(o.unplug_fade) && o.unplug_fade > 0.0 && o.unplug_fade <= 1.0)) {
    ThrowInputError(SourceRef{.field = "--unplug-fade"}, fmt::format("{} s is out of range (0, 1] s", o.unplug_fade));
  }
}

int RunHapticApp(const HapticAppOptions& o) {
  ValidateOptions(o);
  const GuardOptions guard_options = MakeGuardOptions(o);
  std::unique_ptr<HapticDevice> device = MakeDevice(o);
  DeviceGuard guard(*device, guard_options);
  const haptics::RendererConfig config = MakeConfig(o, guard.info());
  haptics::HapticRenderer renderer(config);
  const StationAuth auth = MakeAuthenticators(o);  // null: an open session
  // The LCM threads run SCHED_FIFO below the servo loop, so a pose is sent
  // and a model taken in while other load runs. LCM's own udpm receive
  // thread starts on the first subscription and inherits the scope's policy.
  const int lcm_priority = o.realtime ? std::min(transport::kLcmThreadPriority, o.rt_priority - 1) : 0;
  transport::ScopedThreadFifo lcm_scope(lcm_priority);
  transport::LcmBus bus(o.lcm_url);
  transport::HapticClientLink link(bus, o.session, MakeLinkOptions(o, auth, config));
  lcm_scope.Restore();

  ServoLoop loop(o, guard, renderer, link);  // preallocates everything the loop touches
  std::signal(SIGINT, OnStopSignal);
  std::signal(SIGTERM, OnStopSignal);
  // Helper threads first (they inherit SCHED_OTHER), then our priority.
  link.Start(100, lcm_priority);
  RunOutcome run{};
  if (o.realtime) run.realtime = transport::TryEnableRealtime(o.rt_priority, "haptic loop");
  transport::PrefaultStack();
  Log().info("haptic loop: {} Hz, tool poses at {} Hz, session {}, LCM {}, device {}", o.rate,
             o.rate / loop.tool_every(), o.session, o.lcm_url, device->info().name);

  run.end_reason = loop.Run(g_stop);

  guard.SetForce(Eigen::Vector3d::Zero());
  guard.Stop();
  run.device = SummariseDevice(*device, guard, loop.start_ns(), guard_options, o.rate);
  if (run.realtime.fifo) (void)transport::SetCurrentThreadNormal();
  link.Stop();
  run.csv_rows = loop.FinishCsv();
  LogSummary(run.end_reason, loop, renderer.stats(), link.stats());
  const std::string json = transport::ReportJson(StatsReport(o, run, loop, renderer.stats(), link));
  std::fputs(json.c_str(), stdout);
  std::fputc('\n', stdout);
  std::fflush(stdout);
  if (run.device.stuck) {
    Log().error("device {} stopped answering: no reading for {:.1f} s (its read or write_force blocks); the force "
                "faded to zero and the station stopped",
                device->info().name, kDeviceStuckSeconds);
    return kExitDeviceStuck;
  }
  // A run that never heard a server rendered nothing: say so, and fail.
  if (renderer.stats().models_accepted == 0) {
    Log().error("no model was received from a server on session '{}' ({}): is the server running, with the "
                "same --session, --lcm-url and key?",
                o.session, o.lcm_url);
    return kExitNoModel;
  }
  return 0;
}

}  // namespace cutsim::haptic_client

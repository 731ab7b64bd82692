#include "viewer_client/viewer_app.h"

#include <algorithm>
#include <chrono>
#include <csignal>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <memory>
#include <optional>
#include <sstream>
#include <tuple>

#include <CLI/CLI.hpp>
#include <fmt/format.h>

#include "common/cli/flag_modes.h"
#include "common/core/clock.h"
#include "common/core/error.h"
#include "common/core/install_paths.h"
#include "common/core/log.h"
#include "common/debrief/debrief_command.h"
#include "common/render/camera.h"
#include "common/render/image.h"
#include "common/render/surface_renderer.h"
#include "common/render/video_writer.h"
#include "common/transport/channels.h"
#include "common/transport/dds.h"
#include "common/transport/debrief_control.h"
#include "common/transport/mesh_stream.h"
#include "common/transport/proto_vec.h"
#include "common/transport/report_json.h"
#include "common/web/browser_bridge.h"
#include "cutsim/v1/report.pb.h"

namespace cutsim::viewer {
namespace {

volatile int g_stop = 0;
static_assert(sizeof(std::sig_atomic_t) == sizeof(int));
void OnSignal(int) { g_stop = 1; }

/// Parses "x,y,z" (metres); throws InputError naming the flag.
Eigen::Vector3d ParseVec3(const std::string& text, const std::string& flag) {
  Eigen::Vector3d v;
  std::istringstream in(text);
  char c1 = 0, c2 = 0;
  if (!(in >> v.x() >> c1 >> v.y() >> c2 >> v.z()) || c1 != ',' || c2 != ',' || !v.allFinite()) {
    ThrowInputError({.field = flag}, fmt::format("expected x,y,z in metres, got '{}'", text));
  }
  in >> std::ws;
  if (!in.eof()) ThrowInputError({.field = flag}, fmt::format("trailing text in '{}'", text));
  return v;
}

/// Writes `text` to `path` through a temporary file, so a failed write never
/// replaces a good summary.
void WriteFileAtomically(const std::string& path, const std::string& text) {
  const std::string tmp = path + ".tmp";
  {
    std::ofstream out(tmp, std::ios::trunc);
    out << text << '\n';
    if (!out.flush()) ThrowFileError(path, "cannot write");
  }
  std::filesystem::rename(tmp, path);
}

struct RunSummary {
  int64_t frames = 0;           ///< Frames rendered (all hash-verified).
  int64_t frames_skipped = 0;   ///< Render ticks with no verified current mesh.
  int64_t render_ns = 0;        ///< Render + read-back time, total.
  int64_t local_hash_mismatches = 0;  ///< Re-checks of the held mesh that failed before rendering.
  double join_latency_s = -1;   ///< Start → first verified current mesh.
  uint64_t first_seq = 0, first_hash = 0, last_seq = 0, last_hash = 0;
  double first_sim_time = 0;
  int64_t first_frame_mono_ns = 0;
  int64_t frames_with_tool = 0;
  uint64_t last_cuts = 0;
  double last_session_clock = 0;  ///< s
  double max_force_n = 0;
  v1::SessionMetrics metrics;     ///< as of the last rendered frame
  std::string exit_reason = "signal";
};

v1::ViewerSummary SummaryReport(const ViewerOptions& o, const RunSummary& r,
                                const transport::MeshStreamSubscriberStats& s, const web::BrowserBridge* bridge) {
  using transport::ReportCount;
  v1::ViewerSummary v;
  v.set_session(o.session);
  v.set_frames(ReportCount(r.frames));
  v.set_verified_frames(ReportCount(r.frames));
  v.set_frames_skipped(ReportCount(r.frames_skipped));
  v.set_resyncs(ReportCount(s.resyncs));
  v.set_gaps(ReportCount(s.gaps));
  v.set_hash_checks(ReportCount(s.hash_checks));
  v.set_hash_mismatches(ReportCount(s.hash_mismatches + static_cast<uint64_t>(r.local_hash_mismatches)));
  v.set_bytes_received(static_cast<double>(s.bytes_received));
  v.set_samples(ReportCount(s.samples));
  v.set_snapshots(ReportCount(s.snapshots));
  v.set_deltas(ReportCount(s.deltas));
  v.set_stale_snapshots(ReportCount(s.stale_snapshots));
  v.set_malformed(ReportCount(s.malformed));
  v.set_oversized(ReportCount(s.oversized));
  v.set_foreign_session(ReportCount(s.foreign_session));
  v.set_unknown_topology(ReportCount(s.unknown_topology));
  v.set_ignored(ReportCount(s.ignored));
  v.set_status_messages(ReportCount(s.status));
  v.set_authenticated(s.authenticated);
  v.set_unsigned_samples(ReportCount(s.unsigned_samples));
  v.set_forged(ReportCount(s.forged));
  v.set_replayed(ReportCount(s.replayed));
  v.set_invalid_epoch(ReportCount(s.invalid_epoch));
  v.set_other_server(ReportCount(s.other_server));
  v.set_server_changes(ReportCount(s.server_changes));
  v.set_join_latency_s(r.join_latency_s);
  v.set_render_ms_mean(r.frames > 0 ? 1e-6 * static_cast<double>(r.render_ns) / static_cast<double>(r.frames)
                                    : 0.0);
  v.set_first_seq(static_cast<double>(r.first_seq));
  v.set_first_hash(transport::HexHash(r.first_hash));
  v.set_first_sim_time(r.first_sim_time);
  v.set_first_frame_mono_ns(static_cast<double>(r.first_frame_mono_ns));
  v.set_last_seq(static_cast<double>(r.last_seq));
  v.set_last_hash(transport::HexHash(r.last_hash));
  v.set_width(ReportCount(o.width));
  v.set_height(ReportCount(o.height));
  v.set_exit_reason(r.exit_reason);
  v.set_frames_with_tool(ReportCount(r.frames_with_tool));
  v.set_last_cuts(r.last_cuts);
  v.set_last_session_clock(r.last_session_clock);
  v.set_max_force_n(r.max_force_n);
  v.set_malformed_observed(ReportCount(s.malformed_observed));
  *v.mutable_metrics() = r.metrics;
  if (bridge != nullptr) {
    const web::ObserverServerStats b = bridge->server().stats();
    v.set_browser_frames(ReportCount(bridge->frames_relayed()));
    v.set_browsers_accepted(ReportCount(b.accepted));
    v.set_browsers_refused(ReportCount(b.web.refused_cap + b.web.refused_origin + b.web.refused_token +
                                        b.web.refused_host + b.web.refused_key));
    v.set_browsers_closed(ReportCount(b.closed_incoming + b.closed_slow));
    v.set_browser_bytes_sent(static_cast<double>(b.bytes_sent));
  }
  return v;
}

/// `text` as a JSON string's contents (quotes, backslashes, control characters).
std::string JsonEscape(std::string_view text) {
  std::string out;
  for (const char c : text) {
    if (c == '"' || c == '\\') {
      out += '\\';
      out += c;
    } else if (static_cast<unsigned char>(c) < 0x20 || static_cast<unsigned char>(c) > 0x7e) {
      out += fmt::format("\\u{:04x}", static_cast<unsigned char>(c));
    } else {
      out += c;
    }
  }
  return out;
}

/// An instructor's message: checked as the server checks a command line
/// (common/debrief/debrief_command.h), then sent to the debrief; the reply
/// says which field is wrong, or what went out.
std::string ControlReply(std::string_view message, transport::DebriefControlWriter& control) {
  const debrief::CommandParse parse = debrief::ParseDebriefCommand(message);
  if (!parse.command) {
    return fmt::format(R"({{"type":"control","ok":false,"field":"{}","error":"{}"}})", parse.field,
                       JsonEscape(parse.error));
  }
  const std::string line = debrief::FormatDebriefCommand(*parse.command);
  if (control.matched_readers() == 0) {
    return fmt::format(R"j({{"type":"control","ok":false,"field":"session","error":"no debrief of this session is )j"
                       R"j(listening (cutsim-server --replay FILE --live)","command":"{}"}})j",
                       line);
  }
  if (!control.Send(line)) {
    return fmt::format(R"({{"type":"control","ok":false,"field":"session","error":"the command could not be sent",)"
                       R"("command":"{}"}})",
                       line);
  }
  return fmt::format(R"({{"type":"control","ok":true,"command":"{}"}})", line);
}

/// Draws verified meshes and writes them out: PNG frames, a video, a frame
/// log. The camera frames the first mesh unless --eye/--target set it.
class FrameSink {
 public:
  /// Checks the camera, creates the frame directory and opens the frame log.
  explicit FrameSink(const ViewerOptions& o) : o_(o) {
    if (o.eye) {
      camera_ = render::Camera{.eye = *o.eye, .target = *o.target, .width = o.width, .height = o.height};
      render::ValidateCamera(*camera_);
    }
    if (!o.frames_dir.empty()) std::filesystem::create_directories(o.frames_dir);
    if (!o.frame_log.empty()) {
      frame_log_.open(o.frame_log, std::ios::trunc);
      if (!frame_log_) ThrowFileError(o.frame_log, "cannot open for writing");
    }
  }

  /// Starts ffmpeg when a video is asked for.
  void StartVideo() {
    if (!o_.video.empty()) {
      video_ = std::make_unique<render::FfmpegVideoWriter>(o_.video, o_.width, o_.height, o_.fps);
    }
  }

  /// Renders frame `index` of `mesh` and writes it everywhere asked; adds the
  /// render and read-back time to `*render_ns`. Returns when it was done
  /// (monotonic ns).
  int64_t Draw(const transport::MeshReplica& mesh, const std::optional<v1::ObserverSession>& observed,
               int64_t index, int64_t* render_ns) {
    if (!camera_) camera_ = render::FrameBoundingBox(render::BoundingBox(mesh.world()), o_.width, o_.height);
    const int64_t t0 = MonotonicNs();
    render::RenderOptions ropts;
    ropts.colour_by_scalar = o_.stress;
    if (observed && observed->tools_size() > 0) {
      // The scalpel as the server last placed it, and the force on it.
      const v1::ToolView& tool = observed->tools(0);
      const Eigen::Vector3d tip = transport::FromVec3(tool.tip());
      Eigen::Vector3d dir = transport::FromVec3(tool.blade_dir());
      dir = dir.norm() > 0 ? Eigen::Vector3d(dir.normalized()) : Eigen::Vector3d::UnitZ();
      ropts.tool = render::ToolSegment{.pose = {.tip = tip, .blade_dir = dir}, .length = tool.blade_length()};
      ropts.force = render::ForceOverlay{.at = tip, .force = transport::FromVec3(tool.force()),
                                         .full_scale = o_.force_full_scale};
    }
    const render::Image image = renderer_.Render(
        *camera_, {.positions = mesh.world(),
                   .triangles = mesh.surface(),
                   .opened = mesh.opened(),
                   .vertex_scalar = o_.stress ? std::span<const double>(mesh.stress())
                                              : std::span<const double>()},
        ropts);
    *render_ns += MonotonicNs() - t0;
    if (!o_.frames_dir.empty()) {
      render::WritePng(std::filesystem::path(o_.frames_dir) / fmt::format("frame_{:06d}.png", index), image);
    }
    if (video_) video_->WriteFrame(image);
    const int64_t done_ns = MonotonicNs();
    if (frame_log_) {
      frame_log_ << index << ' ' << mesh.seq() << ' ' << fmt::format("{:016x}", mesh.hash()) << ' '
                 << fmt::format("{:.9g}", mesh.sim_time()) << ' ' << done_ns << '\n';
      frame_log_.flush();
    }
    return done_ns;
  }

  void Close() {
    if (video_) video_->Close();
  }

 private:
  const ViewerOptions& o_;
  render::SurfaceRenderer renderer_;
  std::optional<render::Camera> camera_;
  std::unique_ptr<render::FfmpegVideoWriter> video_;
  std::ofstream frame_log_;
};

/// "file://<absolute path>", or "" (Cyclone's default) for no file.
std::string DdsConfigUri(const std::string& file) {
  return file.empty() ? std::string() : "file://" + std::filesystem::absolute(file).string();
}

/// Why the run ends now (--duration, --exit-when-idle), or null to go on.
const char* LimitReached(const ViewerOptions& o, const transport::MeshStreamSubscriber& sub,
                         int64_t start_ns, int64_t now) {
  if (o.duration && now - start_ns >= static_cast<int64_t>(*o.duration * 1e9)) return "duration";
  if (o.exit_when_idle && sub.last_sample_ns() > 0 &&
      now - sub.last_sample_ns() >= static_cast<int64_t>(*o.exit_when_idle * 1e9)) {
    return "idle";
  }
  return nullptr;
}

/// The replica verified the publisher's hash when it applied the last
/// snapshot or delta; this rechecks the state about to be drawn against it.
bool HeldMeshVerified(const transport::MeshReplica& mesh, RunSummary& r) {
  if (mesh.ComputeHash() == mesh.hash()) return true;
  ++r.local_hash_mismatches;
  Log().error("held mesh no longer matches its hash (seq {}); not rendered", mesh.seq());
  return false;
}

/// Counts a rendered frame; the first one also gives the join latency.
void NoteFrame(const transport::MeshReplica& mesh, const std::optional<v1::ObserverSession>& observed,
               int64_t start_ns, int64_t done_ns, RunSummary& r) {
  if (observed) {
    r.last_cuts = observed->cuts();
    r.last_session_clock = observed->sim_time();
    r.metrics = observed->metrics();
    if (observed->tools_size() > 0) {
      ++r.frames_with_tool;
      r.max_force_n = std::max(r.max_force_n, transport::FromVec3(observed->tools(0).force()).norm());
    }
  }
  if (r.frames == 0) {
    r.first_seq = mesh.seq();
    r.first_hash = mesh.hash();
    r.first_sim_time = mesh.sim_time();
    r.first_frame_mono_ns = done_ns;
    r.join_latency_s = 1e-9 * static_cast<double>(done_ns - start_ns);
    Log().info("first verified frame: seq {} hash {:016x} after {:.3f} s", mesh.seq(), mesh.hash(),
               r.join_latency_s);
  }
  r.last_seq = mesh.seq();
  r.last_hash = mesh.hash();
  ++r.frames;
}

}  // namespace

int ViewerApp::ParseArgs(int argc, char** argv) {
  CLI::App app{"cutsim-viewer: watches a cutsim session over DDS and renders it offscreen"};
  std::string eye, target;
  app.add_option("--session", options_.session, "Session to watch")->capture_default_str();
  app.add_option("--dds-domain", options_.dds_domain, "DDS domain id")
      ->check(CLI::Range(0u, transport::kMaxDdsDomainId))
      ->capture_default_str();
  app.add_option("--dds-config", options_.dds_config,
                 "Cyclone DDS XML file (default: $CYCLONEDDS_URI, else loopback only)")
      ->check(CLI::ExistingFile);
  app.add_option("--frames", options_.frames_dir, "Write PNG frames to this directory");
  app.add_option("--video", options_.video, "Write a video (needs ffmpeg), e.g. out.mp4");
  app.add_option("--fps", options_.fps, "Render rate, Hz (independent of the physics rate)")
      ->check(CLI::Range(0.1, 240.0))
      ->capture_default_str();
  app.add_option("--width", options_.width, "Image width, pixels")
      ->check(CLI::Range(16, 8192))
      ->capture_default_str();
  app.add_option("--height", options_.height, "Image height, pixels")
      ->check(CLI::Range(16, 8192))
      ->capture_default_str();
  app.add_option("--eye", eye, "Camera position x,y,z (m); default frames the first mesh");
  app.add_option("--target", target, "Camera target x,y,z (m)");
  app.add_flag("--stress", options_.stress, "Colour intact faces by the per-node stress");
  app.add_option("--force-full-scale", options_.force_full_scale,
                 "Force on the tool (N) that fills the force gauge and draws the arrow half the scene's size")
      ->check(CLI::Range(1e-6, 1e6));
  app.add_option("--max-frames", options_.max_frames, "Exit after rendering N frames")
      ->check(CLI::PositiveNumber);
  app.add_option("--duration", options_.duration, "Exit after S seconds")->check(CLI::PositiveNumber);
  app.add_option("--exit-when-idle", options_.exit_when_idle,
                 "Exit 0 when no sample arrived for S seconds after some did")
      ->check(CLI::PositiveNumber);
  app.add_option("--summary", options_.summary, "Write the JSON summary to this file");
  app.add_option("--frame-log", options_.frame_log,
                 "Write one line per rendered frame: index seq hash sim_time mono_ns");
  app.add_option("--log-level", options_.log_level, "trace, debug, info, warn, error, off");
  app.add_option("--serve", options_.serve,
                 "Serve the session to browsers at HOST:PORT (loopback unless --token-file is given)");
  app.add_option("--key-file", options_.key_file,
                 "Session key file (hex): only mesh frames signed with it are shown "
                 "(default $CUTSIM_SESSION_KEY; neither: an open session)");
  app.add_option("--lab", options_.lab,
                 "Serve the lab page at HOST:PORT: every session on the DDS domain, listed and watched side by "
                 "side (loopback unless --token-file is given)");
  // The browser page's flags act only with --serve or --lab; the rest always.
  cli::FlagModes modes({"a viewer without --serve", "--serve", "--lab"});
  constexpr cli::ModeSet kServing = (1U << 1) | (1U << 2);
  constexpr cli::ModeSet kLab = 1U << 2;
  options_.lab_root = (DataDir() / "web" / "lab").string();
  modes.Declare(app.add_option("--lab-root", options_.lab_root,
                               "The lab page's files (web/lab; default: the installed data folder, else the source "
                               "tree)")
                    ->capture_default_str(),
                kLab);
  modes.Declare(app.add_option("--history", options_.history,
                               "The lab's score history (cutsim-server --history): the lab page shows each "
                               "listed trainee's trend over their finished sessions"),
                kLab);
  modes.Declare(app.add_option("--host-name", options_.host_names,
                               "A further name browsers may open the page at (the Host and Origin it accepts; "
                               "repeat for more)"),
                kServing);
  modes.Declare(app.add_option("--token-file", options_.token_file,
                               "Observers' token (16-128 chars of A-Za-z0-9_-): browsers need ?token=… in the URL"),
                kServing);
  modes.Declare(app.add_option("--instructor-token-file", options_.instructor_token_file,
                               "The instructor's token (16-128 chars of A-Za-z0-9_-, not the observers'): a page "
                               "opened with &instructor=… steers a debrief (cutsim-server --replay FILE --live): "
                               "play, pause, seek, cut steps, speed; other pages stay read-only")
                    ->check(CLI::ExistingFile),
                1U << 1);
  options_.web_root = (DataDir() / "web" / "observer").string();
  modes.Declare(app.add_option("--web-root", options_.web_root,
                               "The observer page's files (web/observer with three.js under node_modules/three; "
                               "default: the installed data folder, share/cutsim beside bin/, else the source tree)")
                    ->capture_default_str(),
                kServing);
  modes.DeclareRest(app, modes.all());
  try {
    app.parse(argc, argv);
  } catch (const CLI::ParseError& e) {
    return app.exit(e);
  }
  // A flag that does nothing without --serve is refused, not ignored.
  if (!options_.serve.empty() && !options_.lab.empty()) {
    ThrowInputError({.field = "--lab"}, "--serve watches one session and --lab every session: give one of them");
  }
  const int mode = !options_.lab.empty() ? 2 : options_.serve.empty() ? 0 : 1;
  if (const std::optional<std::string> refusal = modes.Refusal(app, mode)) {
    std::fprintf(stderr, "%s\n", refusal->c_str());
    return 2;
  }
  transport::ValidateSessionName(options_.session, "--session");
  if (!eye.empty()) options_.eye = ParseVec3(eye, "--eye");
  if (!target.empty()) options_.target = ParseVec3(target, "--target");
  if (options_.eye.has_value() != options_.target.has_value()) {
    ThrowInputError({.field = options_.eye ? "--target" : "--eye"},
                    "--eye and --target go together");
  }
  if (!options_.video.empty() && !render::FfmpegVideoWriter::Available()) {
    ThrowInputError({.file = options_.video, .field = "--video"},
                    "ffmpeg is not installed (apt-get install ffmpeg), so no video can be written; "
                    "use --frames DIR for PNG frames");
  }
  return -1;
}

int ViewerApp::Run() {
  InitLogging("cutsim-viewer", options_.log_level);
  std::signal(SIGINT, OnSignal);
  std::signal(SIGTERM, OnSignal);
  const ViewerOptions& o = options_;
  if (!o.lab.empty()) return RunLab(o, g_stop);
  const int64_t start_ns = MonotonicNs();
  FrameSink sink(o);
  transport::DdsParticipant participant(o.dds_domain, DdsConfigUri(o.dds_config));
  std::optional<transport::SessionKey> key = transport::LoadSessionKey(o.key_file);
  if (key) {
    Log().info("session '{}': only mesh frames signed with the session key are shown", o.session);
  } else {
    Log().warn("session '{}' is OPEN: no session key (--key-file or ${}), so the frames shown are "
               "not authenticated",
               o.session, transport::kSessionKeyEnv);
  }
  transport::MeshStreamSubscriber sub(participant, o.session, key);
  std::unique_ptr<transport::DebriefControlWriter> control;  // with --instructor-token-file
  std::unique_ptr<web::BrowserBridge> bridge;
  if (!o.serve.empty()) {
    web::ObserverServerOptions so;
    std::tie(so.address, so.port) = web::ParseHostPort(o.serve, "--serve");
    if (!o.token_file.empty()) so.token = web::LoadObserverToken(o.token_file);
    so.host_names = o.host_names;
    so.files = web::ObserverPageFiles(o.web_root);
    if (!o.instructor_token_file.empty()) {
      so.instructor_token = web::LoadObserverToken(o.instructor_token_file);
      if (so.instructor_token == so.token) {
        ThrowInputError({.file = o.instructor_token_file, .field = "--instructor-token-file"},
                        "the instructor's token must differ from the observers' (--token-file)");
      }
      control = std::make_unique<transport::DebriefControlWriter>(participant, o.session, key);
      so.on_control = [c = control.get()](std::string_view message) { return ControlReply(message, *c); };
    }
    const std::string instructor = so.instructor_token;
    bridge = std::make_unique<web::BrowserBridge>(std::move(so), o.session);
    // On stdout, for scripts: the address a browser opens.
    const std::string url = bridge->server().Url();
    std::printf("observers: %s\n", url.c_str());
    if (!instructor.empty()) {
      std::printf("instructor: %s%sinstructor=%s\n", url.c_str(), url.find('?') == std::string::npos ? "?" : "&",
                  instructor.c_str());
    }
    std::fflush(stdout);
  }
  // Rendering offscreen is for frames and videos; a pure bridge skips it.
  const bool render = bridge == nullptr || !o.frames_dir.empty() || !o.video.empty();
  Log().info("watching session '{}' on DDS domain {} at {} fps", o.session, o.dds_domain, o.fps);
  sink.StartVideo();

  RunSummary r;
  const auto period_ns = static_cast<int64_t>(1e9 / o.fps);
  int64_t next_tick = start_ns + period_ns;
  while (!g_stop) {
    const int64_t now = MonotonicNs();
    if (const char* reason = LimitReached(o, sub, start_ns, now)) {
      r.exit_reason = reason;
      break;
    }
    if (now < next_tick) {
      // Bounded WaitSet wait: samples are processed as they come, and the
      // loop still notices the next tick and signals.
      sub.Poll(std::chrono::nanoseconds(std::min<int64_t>(next_tick - now, 50'000'000)));
      if (bridge) bridge->Relay(sub);
      continue;
    }
    next_tick += period_ns;
    if (next_tick < now) next_tick = now + period_ns;  // fell behind: skip ticks, do not burst
    const transport::MeshReplica& mesh = sub.replica();
    if (!sub.current() || !HeldMeshVerified(mesh, r)) {
      ++r.frames_skipped;
      continue;
    }
    if (!render) continue;
    const int64_t done_ns = sink.Draw(mesh, sub.observed(), r.frames, &r.render_ns);
    NoteFrame(mesh, sub.observed(), start_ns, done_ns, r);
    if (o.max_frames && r.frames >= *o.max_frames) {
      r.exit_reason = "max_frames";
      break;
    }
  }
  sink.Close();
  const std::string json = transport::ReportJson(SummaryReport(o, r, sub.stats(), bridge.get()));
  // Always on stderr, whatever the log level (stdout stays free).
  std::fprintf(stderr, "cutsim-viewer: summary: %s\n", json.c_str());
  if (!o.summary.empty()) WriteFileAtomically(o.summary, json);
  return 0;
}

}  // namespace cutsim::viewer

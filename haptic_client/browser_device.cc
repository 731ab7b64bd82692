#include "haptic_client/browser_device.h"

#include <sys/stat.h>

#include <algorithm>
#include <charconv>
#include <cmath>
#include <filesystem>
#include <fstream>

#include <fmt/format.h>
#include <openssl/evp.h>
#include <openssl/hmac.h>

#include "common/core/clock.h"
#include "common/core/error.h"
#include "common/transport/tool_auth.h"
#include "common/web/trainee_server.h"

namespace cutsim::haptic_client {
namespace {

constexpr const char* kTokenLabel = "cutsim trainee page v1";
constexpr int64_t kMinDelayNs = 4'000'000;
constexpr int64_t kMaxDelayNs = 50'000'000;

/// Splits off the next space-separated token of `text`.
std::string_view NextToken(std::string_view* text) {
  const size_t start = text->find_first_not_of(' ');
  if (start == std::string_view::npos) {
    *text = {};
    return {};
  }
  text->remove_prefix(start);
  const size_t end = text->find(' ');
  const std::string_view token = text->substr(0, end);
  text->remove_prefix(end == std::string_view::npos ? text->size() : end);
  return token;
}

/// A whole token as a double; false if it is not exactly one number.
bool ParseNumber(std::string_view token, double* out) {
  if (token.empty()) return false;
  const auto [end, ec] = std::from_chars(token.data(), token.data() + token.size(), *out);
  return ec == std::errc() && end == token.data() + token.size();
}

ToolPose Lerp(const ToolPose& a, const ToolPose& b, double w) {
  ToolPose p;
  p.tip = (1.0 - w) * a.tip + w * b.tip;
  const Eigen::Vector3d d = (1.0 - w) * a.blade_dir + w * b.blade_dir;
  const double n = d.norm();
  p.blade_dir = n > 1e-9 ? Eigen::Vector3d(d / n) : b.blade_dir;
  return p;
}

}  // namespace

SampleError ParseBrowserSample(std::string_view text, const DeviceInfo& info, double previous_ms,
                               BrowserSample* out) noexcept {
  if (NextToken(&text) != "p") return SampleError::kFormat;
  std::array<double, 8> v{};
  for (double& x : v) {
    if (!ParseNumber(NextToken(&text), &x)) return SampleError::kFormat;
  }
  if (!NextToken(&text).empty()) return SampleError::kFormat;
  for (const double x : v) {
    if (!std::isfinite(x)) return SampleError::kNotFinite;
  }
  const double t = v[0];
  if (t < 0.0 || t > 1e12) return SampleError::kRange;
  for (int i = 1; i <= 3; ++i) {
    if (v[i] < 0.0 || v[i] > 1.0) return SampleError::kRange;
  }
  const Eigen::Vector3d dir(v[4], v[5], v[6]);
  const double n = dir.norm();
  if (n < 0.9 || n > 1.1) return SampleError::kDirection;
  if (v[7] != std::floor(v[7]) || v[7] < 0.0 || v[7] > 3.0) return SampleError::kButtons;
  if (previous_ms >= 0.0 && t < previous_ms) return SampleError::kTimeBackwards;
  out->page_ms = t;
  const Eigen::Vector3d u(v[1], v[2], v[3]);
  out->pose.tip = info.workspace_min + u.cwiseProduct(info.workspace_max - info.workspace_min);
  out->pose.blade_dir = dir / n;
  out->buttons = static_cast<uint32_t>(v[7]);
  return SampleError::kNone;
}

void InterpolatePose(const SamplePair& pair, int64_t now_ns, DeviceState* state, double* used_ms) noexcept {
  state->velocity.setZero();
  if (pair.count == 0) {
    state->buttons = 0;
    return;
  }
  const BrowserSample& b = pair.newer;
  if (pair.count == 1) {
    state->pose = b.pose;
    state->buttons = b.buttons;
    *used_ms = b.page_ms;
    return;
  }
  const BrowserSample& a = pair.older;
  const double render_ms = 1e-6 * static_cast<double>(now_ns - pair.delay_ns - pair.offset_ns);
  const double span_ms = b.page_ms - a.page_ms;
  if (render_ms >= b.page_ms || span_ms <= 0.0) {
    state->pose = b.pose;
    state->buttons = b.buttons;
    *used_ms = b.page_ms;
    return;
  }
  if (render_ms <= a.page_ms) {
    state->pose = a.pose;
    state->buttons = a.buttons;
    *used_ms = a.page_ms;
    return;
  }
  const double w = (render_ms - a.page_ms) / span_ms;
  state->pose = Lerp(a.pose, b.pose, w);
  state->velocity = (b.pose.tip - a.pose.tip) / (1e-3 * span_ms);
  state->buttons = a.buttons;  // a button changes at the sample that carries it
  *used_ms = b.page_ms;
}

std::string TraineeToken(const transport::SessionKey& key) {
  std::array<unsigned char, EVP_MAX_MD_SIZE> mac{};
  unsigned int len = 0;
  const std::string_view label(kTokenLabel);
  HMAC(EVP_sha256(), key.bytes.data(), static_cast<int>(key.size), reinterpret_cast<const unsigned char*>(label.data()),
       label.size(), mac.data(), &len);
  std::string hex;
  for (unsigned int i = 0; i < len; ++i) hex += fmt::format("{:02x}", mac[i]);
  return hex;
}

uint64_t BrowserDeviceStats::refused_total() const {
  uint64_t n = 0;
  for (const uint64_t r : refused) n += r;
  return n;
}

DeviceInfo BrowserDevice::DefaultInfo() {
  DeviceInfo info;
  info.name = "browser";
  info.max_force = 8.0;
  info.rate_hz = 0.0;  // samples are interpolated to every tick
  // 60 × 60 × 40 mm: the page's square view maps to equal x and y spans.
  info.workspace_min = {-0.015, -0.03, -0.02};
  info.workspace_max = {0.045, 0.03, 0.02};
  return info;
}

std::map<std::string, std::filesystem::path> TraineePageFiles(const std::string& page_dir,
                                                             const std::string& three_dir) {
  const std::filesystem::path dir(page_dir);
  const std::filesystem::path three =
      three_dir.empty() ? dir / ".." / "observer" / "node_modules" / "three" : std::filesystem::path(three_dir);
  return {{"/index.html", dir / "index.html"},
          {"/trainee.js", dir / "trainee.js"},
          {"/trainee.css", dir / "trainee.css"},
          {"/common/scalpel.js", dir / ".." / "common" / "scalpel.js"},
          {"/common/plan_line.js", dir / ".." / "common" / "plan_line.js"},
          {"/common/mesh_frames.js", dir / ".." / "common" / "mesh_frames.js"},
          {"/vendor/three.module.js", three / "build" / "three.module.js"},
          {"/vendor/three.core.js", three / "build" / "three.core.js"},
          {"/vendor/OrbitControls.js", three / "examples" / "jsm" / "controls" / "OrbitControls.js"}};
}

namespace {

/// The page's first message: the workspace, the mapping to the world, the
/// blade and the plan.
std::string Hello(const DeviceInfo& info, const BrowserDeviceOptions& o) {
  const Eigen::Vector3d& lo = info.workspace_min;
  const Eigen::Vector3d& hi = info.workspace_max;
  std::string plan;
  for (const Eigen::Vector3d& p : o.planned_incision) {
    plan += fmt::format("{}[{},{},{}]", plan.empty() ? "" : ",", p.x(), p.y(), p.z());
  }
  return fmt::format(R"({{"kind":"hello","workspace_min":[{},{},{}],"workspace_max":[{},{},{}],"max_force":{},)"
                     R"("world_scale":{},"world_offset":[{},{},{}],"blade_length":{},"plan":[{}],"mesh":{}}})",
                     lo.x(), lo.y(), lo.z(), hi.x(), hi.y(), hi.z(), info.max_force, o.world_scale,
                     o.world_offset.x(), o.world_offset.y(), o.world_offset.z(), o.blade_length, plan,
                     o.view ? "true" : "false");
}

}  // namespace

BrowserDevice::BrowserDevice(const BrowserDeviceOptions& o, DeviceInfo info)
    : info_(std::move(info)), stream_(info_) {
  if (!(std::isfinite(o.world_scale) && o.world_scale > 0.0) || !o.world_offset.allFinite()) {
    ThrowInputError({.field = "--workspace-scale"}, "the workspace mapping must be finite with a positive scale");
  }
  if (!(std::isfinite(o.blade_length) && o.blade_length > 0.0 && o.blade_length < 1.0)) {
    ThrowInputError({.field = "tool.blade_length"}, fmt::format("{} m is out of range (0, 1) m", o.blade_length));
  }
  hello_ = Hello(info_, o);
  web::TraineeServerOptions so;
  so.address = o.address;
  so.port = o.port;
  so.token = o.token;
  so.host_names = o.host_names;
  so.files = TraineePageFiles(o.page_dir, o.three_dir);
  web::TraineeHandlers h;
  h.on_open = [this] { return OnOpen(); };
  h.on_message = [this](std::string_view m, int64_t t) { OnMessage(m, t); };
  h.frame = [this] { return MakeFrame(); };
  h.urgent = [this] { return FrameIsUrgent(); };
  h.on_close = [this] { OnClose(); };
  // Before any page: the tip above the middle of the workspace, clear of the tissue.
  loop_pair_.count = 1;
  loop_pair_.newer.page_ms = -1.0;
  loop_pair_.newer.pose.tip = 0.5 * (info_.workspace_min + info_.workspace_max);
  loop_pair_.newer.pose.tip.z() = info_.workspace_max.z();
  server_ = std::make_unique<web::TraineeServer>(std::move(so), std::move(h));
  if (o.view) view_ = std::make_unique<TraineeView>(*server_, *o.view);
  url_ = server_->BaseUrl() + "?token=" + o.token;
  if (!o.url_file.empty()) {
    std::ofstream f(o.url_file, std::ios::trunc);
    if (!f) ThrowFileError(o.url_file, "cannot write the trainee page's URL");
    ::chmod(o.url_file.c_str(), 0600);
    f << url_ << '\n';
  }
}

BrowserDevice::~BrowserDevice() {
  view_.reset();
  server_.reset();
}

void BrowserDevice::Start(int64_t /*start_ns*/) {}

void BrowserDevice::Read(int64_t now_ns, DeviceState* state) noexcept {
  samples_.Read(&loop_pair_);
  InterpolatePose(loop_pair_, now_ns, state, &loop_frame_.used_ms);
  state->done = false;
  state->lost = false;
  loop_frame_.tip = state->pose.tip;
  loop_frame_.buttons = state->buttons;
}

void BrowserDevice::SetForce(const Eigen::Vector3d& force) noexcept {
  loop_frame_.force = force;
  frames_.Write(loop_frame_);
}

void BrowserDevice::ShowModel(uint64_t cuts, bool contact) noexcept {
  loop_frame_.cuts = cuts;
  loop_frame_.contact = contact;
}

void BrowserDevice::Stop() noexcept {
  loop_frame_.force.setZero();
  frames_.Write(loop_frame_);
}

std::string BrowserDevice::url() const { return url_; }

BrowserDeviceStats BrowserDevice::stats() const {
  const std::lock_guard lock(stats_mu_);
  return stats_;
}

SampleError SampleStream::Push(std::string_view text, int64_t receive_ns, bool* heartbeat, bool* reanchored) noexcept {
  *heartbeat = text == "h";
  *reanchored = false;
  if (*heartbeat) return SampleError::kNone;
  BrowserSample s;
  const double previous = pair_.count > 0 ? pair_.newer.page_ms : -1.0;
  SampleError e = ParseBrowserSample(text, info_, previous, &s);
  const auto page_ns = static_cast<int64_t>(std::llround(s.page_ms * 1e6));
  if (e == SampleError::kNone && pair_.count > 0) {
    // Within the window of the stream's clock at arrival.
    const double skew_ms = 1e-6 * static_cast<double>(page_ns + pair_.offset_ns - receive_ns);
    if (std::abs(skew_ms) > kClockWindowMs) e = SampleError::kClock;
  }
  if (e != SampleError::kClock && e != SampleError::kTimeBackwards) {
    time_refused_since_ns_ = -1;
    if (e != SampleError::kNone) return e;
  } else if (time_refused_since_ns_ < 0) {
    time_refused_since_ns_ = receive_ns;
    return e;
  } else if (1e-6 * static_cast<double>(receive_ns - time_refused_since_ns_) < kReanchorMs ||
             ParseBrowserSample(text, info_, -1.0, &s) != SampleError::kNone) {
    return e;
  } else {
    // Every sample refused for its time for a while: the page's clock
    // restarted (or its first sample was wild). Start the stream's clock
    // again from this sample.
    *reanchored = true;
    time_refused_since_ns_ = -1;
    pair_.count = 0;
  }
  const int64_t offset = receive_ns - page_ns;
  if (pair_.count == 0 || offset < pair_.offset_ns) pair_.offset_ns = offset;
  if (pair_.count > 0) {
    // The mean input period (exponential average), the render delay.
    const double gap = std::clamp(s.page_ms - pair_.newer.page_ms, 0.0, 100.0);
    interval_ms_ = 0.9 * interval_ms_ + 0.1 * gap;
    pair_.delay_ns = std::clamp(static_cast<int64_t>(interval_ms_ * 1e6), kMinDelayNs, kMaxDelayNs);
    pair_.older = pair_.newer;
  }
  pair_.newer = s;
  pair_.count = std::min(pair_.count + 1, 2);
  return SampleError::kNone;
}

void SampleStream::Restart() noexcept {
  pair_.count = 0;
  time_refused_since_ns_ = -1;
}

void SampleStream::Release() noexcept {
  if (pair_.count == 0) return;
  pair_.newer.buttons = 0;
  pair_.older = pair_.newer;
  pair_.count = 1;
}

void BrowserDevice::OnMessage(std::string_view text, int64_t receive_ns) noexcept {
  bool heartbeat = false;
  bool reanchored = false;
  const SampleError e = stream_.Push(text, receive_ns, &heartbeat, &reanchored);
  {
    const std::lock_guard lock(stats_mu_);
    if (e != SampleError::kNone) {
      ++stats_.refused[static_cast<size_t>(e)];
      return;
    }
    if (heartbeat) {
      ++stats_.heartbeats;
      return;
    }
    ++stats_.samples;
    if (reanchored) ++stats_.reanchors;
  }
  samples_.Write(stream_.pair());
}

std::string BrowserDevice::OnOpen() {
  {
    const std::lock_guard lock(stats_mu_);
    ++stats_.connections;
  }
  stream_.Restart();  // a new page has a new clock
  return hello_;
}

void BrowserDevice::OnClose() noexcept {
  // The tool holds its pose with the buttons released.
  if (stream_.pair().count == 0) return;
  stream_.Release();
  samples_.Write(stream_.pair());
  stream_.Restart();
}

bool BrowserDevice::FrameIsUrgent() noexcept {
  frames_.Read(&io_frame_);
  return io_frame_.used_ms != sent_used_ms_;
}

std::string BrowserDevice::MakeFrame() {
  frames_.Read(&io_frame_);
  const BrowserFrame& f = io_frame_;
  sent_used_ms_ = f.used_ms;
  return fmt::format(R"({{"kind":"force","force":[{:.5f},{:.5f},{:.5f}],"tip":[{:.6f},{:.6f},{:.6f}],)"
                     R"("used_ms":{:.3f},"cuts":{},"contact":{},"buttons":{},"max_force":{}}})",
                     f.force.x(), f.force.y(), f.force.z(), f.tip.x(), f.tip.y(), f.tip.z(), f.used_ms, f.cuts,
                     f.contact ? "true" : "false", f.buttons, info_.max_force);
}

}  // namespace cutsim::haptic_client

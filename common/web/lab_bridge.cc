#include "common/web/lab_bridge.h"

#include <cmath>
#include <deque>
#include <utility>

#include <fmt/format.h>

#include "common/core/clock.h"
#include "common/core/log.h"

namespace cutsim::web {

std::map<std::string, std::filesystem::path> LabPageFiles(const std::filesystem::path& lab_root,
                                                         const std::filesystem::path& observer_root) {
  std::map<std::string, std::filesystem::path> files = ObserverPageFiles(observer_root);
  files["/observer.html"] = files.at("/index.html");
  files["/index.html"] = lab_root / "index.html";
  files["/lab.js"] = lab_root / "lab.js";
  files["/lab.css"] = lab_root / "lab.css";
  return files;
}

namespace {

/// `text` as a JSON string: printable ASCII kept (quote and backslash
/// escaped), everything else '?', so the text frame is valid UTF-8 whatever
/// a status claimed.
std::string JsonString(const std::string& text) {
  std::string out = "\"";
  for (const char c : text) {
    const auto u = static_cast<unsigned char>(c);
    if (c == '"' || c == '\\') {
      out += '\\';
      out += c;
    } else if (u >= 0x20 && u < 0x7f) {
      out += c;
    } else {
      out += '?';
    }
  }
  return out + "\"";
}

/// A number, or null when it is not finite.
std::string JsonNumber(double v) { return std::isfinite(v) ? fmt::format("{:.6g}", v) : std::string("null"); }

std::string MetricsJson(const v1::SessionMetrics& m) {
  return fmt::format(
      "{{\"peak_force\":{},\"mean_force\":{},\"path_length\":{},\"contact_time\":{},\"cut_off_volume\":{},"
      "\"opened_area\":{},\"max_stress_outside\":{}}}",
      JsonNumber(m.peak_force()), JsonNumber(m.mean_force()), JsonNumber(m.path_length()),
      JsonNumber(m.contact_time()), JsonNumber(m.cut_off_volume()), JsonNumber(m.opened_area()),
      JsonNumber(m.max_stress_outside()));
}

std::string ScoreJson(const v1::IncisionScore& s) {
  return fmt::format(
      "{{\"mean_deviation\":{},\"max_deviation\":{},\"depth_error\":{},\"coverage\":{},\"opened_area_outside\":{},"
      "\"peak_force\":{},\"duration\":{}}}",
      JsonNumber(s.mean_deviation()), JsonNumber(s.max_deviation()), JsonNumber(s.depth_error()),
      JsonNumber(s.coverage()), JsonNumber(s.opened_area_outside()), JsonNumber(s.peak_force()),
      JsonNumber(s.duration()));
}

std::string TrendJson(const std::vector<TrendPoint>& points) {
  std::string out = "[";
  for (size_t i = 0; i < points.size(); ++i) {
    const TrendPoint& p = points[i];
    out += fmt::format("{}{{\"finished\":{},\"duration\":{},\"mean_deviation\":{},\"depth_error\":{},"
                       "\"peak_force\":{}}}",
                       i ? "," : "", p.finished_unix_s, JsonNumber(p.duration), JsonNumber(p.mean_deviation),
                       JsonNumber(p.depth_error), JsonNumber(p.peak_force));
  }
  return out + "]";
}

}  // namespace

std::string LabListJson(const std::vector<LabSessionView>& sessions, bool authenticated, const Trends& trends) {
  std::string out = fmt::format("{{\"type\":\"lab\",\"authenticated\":{},\"sessions\":[", authenticated);
  bool first = true;
  for (const LabSessionView& v : sessions) {
    const v1::SessionStatus& st = v.entry.status;
    if (!first) out += ',';
    first = false;
    out += fmt::format(
        "{{\"session\":{},\"scene\":{},\"trainee\":{},\"live\":{},\"trainee_connected\":{},\"cuts\":{},"
        "\"sim_time\":{},\"wall_time\":{},\"overruns_per_s\":{},\"watched\":{},\"current\":{},"
        "\"frame_age_ms\":{},\"frames_per_s\":{},\"bridge_gaps\":{},\"resyncs\":{},\"metrics\":{},\"score\":{},"
        "\"trend\":{}}}",
        JsonString(v.entry.session), JsonString(st.scene()), JsonString(st.trainee()), v.entry.live,
        v.entry.trainee_connected, st.cuts(), JsonNumber(st.sim_time()), JsonNumber(st.wall_time()),
        JsonNumber(v.entry.overruns_per_s), v.watched, v.current,
        v.frame_age_ms >= 0 ? JsonNumber(v.frame_age_ms) : std::string("null"), JsonNumber(v.frames_per_s),
        v.bridge_gaps, v.resyncs, v.metrics ? MetricsJson(*v.metrics) : std::string("null"),
        st.has_score() ? ScoreJson(st.score()) : std::string("null"),
        [&] {
          const auto it = trends.find(st.trainee());
          return it != trends.end() && !st.trainee().empty() ? TrendJson(it->second) : std::string("[]");
        }());
  }
  return out + "]}";
}

/// One session whose mesh stream the bridge reads.
struct LabBridge::Watched {
  Watched(transport::DdsParticipant& participant, const std::string& session,
          const std::optional<transport::SessionKey>& key)
      : sub(participant, session, key), relay(session) {}
  transport::MeshStreamSubscriber sub;
  SessionRelay relay;
  std::deque<int64_t> relayed_ns;  // monotonic times of the frames relayed within the last 2 s
};

namespace {
constexpr int64_t kRateWindowNs = 2'000'000'000;
}  // namespace

LabBridge::LabBridge(transport::DdsParticipant& participant, LabBridgeOptions options)
    : participant_(participant),
      options_(std::move(options)),
      server_([this] {
        ObserverServerOptions so = options_.server;
        so.channels = true;
        return std::make_unique<ObserverServer>(std::move(so));
      }()),
      directory_(participant, options_.directory) {}

LabBridge::~LabBridge() = default;

void LabBridge::Poll(std::chrono::nanoseconds timeout) {
  int clients = -1;
  for (auto& [name, w] : watched_) {
    w->sub.Poll(std::chrono::nanoseconds(0));
    if (clients < 0 && w->sub.state_version() != 0) clients = server_->stats().clients;
    if (w->relay.Relay(w->sub, *server_, name, clients)) {
      const int64_t now = MonotonicNs();
      w->relayed_ns.push_back(now);
      while (!w->relayed_ns.empty() && now - w->relayed_ns.front() > kRateWindowNs) w->relayed_ns.pop_front();
      ++stats_.frames_relayed;
    }
  }
  directory_.Poll(timeout);
  const int64_t now = MonotonicNs();
  if (now >= next_list_ns_) {
    next_list_ns_ = now + std::chrono::nanoseconds(options_.list_period).count();
    SendList();
  }
}

void LabBridge::UpdateWatched(const std::vector<transport::SessionEntry>& entries) {
  // Live sessions get a reader (up to the cap); sessions the directory no
  // longer holds lose theirs and their channel. A stopped session keeps its
  // reader, so a server that comes back is shown at once.
  std::map<std::string, bool> listed;
  for (const transport::SessionEntry& e : entries) listed[e.session] = e.live;
  for (auto it = watched_.begin(); it != watched_.end();) {
    if (!listed.contains(it->first)) {
      server_->SetJoinMessages(it->first, {});
      it = watched_.erase(it);
    } else {
      ++it;
    }
  }
  for (const auto& [name, live] : listed) {
    if (!live || watched_.contains(name)) continue;
    if (watched_.size() >= options_.max_watched) {
      ++stats_.refused_watch;
      continue;
    }
    watched_[name] = std::make_unique<Watched>(participant_, name, options_.directory.key);
    Log().info("lab: watching session '{}'", name);
  }
}

std::vector<LabSessionView> LabBridge::Views() {
  const int64_t now = MonotonicNs();
  const std::vector<transport::SessionEntry> entries = directory_.Entries(now);
  UpdateWatched(entries);
  std::vector<LabSessionView> views;
  views.reserve(entries.size());
  stats_.live = 0;
  for (const transport::SessionEntry& e : entries) {
    LabSessionView v;
    v.entry = e;
    if (e.live) ++stats_.live;
    if (const auto it = watched_.find(e.session); it != watched_.end()) {
      Watched& w = *it->second;
      while (!w.relayed_ns.empty() && now - w.relayed_ns.front() > kRateWindowNs) w.relayed_ns.pop_front();
      v.watched = true;
      v.current = w.sub.current();
      v.frame_age_ms = w.sub.last_sample_ns() > 0 ? 1e-6 * static_cast<double>(now - w.sub.last_sample_ns()) : -1;
      v.frames_per_s = static_cast<double>(w.relayed_ns.size()) / (1e-9 * kRateWindowNs);
      v.bridge_gaps = w.sub.stats().gaps;
      v.resyncs = w.sub.stats().resyncs;
      if (w.sub.observed()) v.metrics = w.sub.observed()->metrics();
    }
    views.push_back(std::move(v));
  }
  stats_.sessions = views.size();
  stats_.watched = watched_.size();
  return views;
}

void LabBridge::SendList() {
  auto text = std::make_shared<const std::string>(LabListJson(Views(), directory_.authenticated(), trends_));
  server_->SetJoinMessages("", {{text, false}});
  server_->Broadcast("", {{text, false}});
  ++stats_.lists_sent;
}

}  // namespace cutsim::web

// What the lab view costs: N sessions published on a DDS domain (in this
// process: a 5×5×5 box per session, about the ligament's surface, deformed
// by a moving bump every frame at 30 frames/s, with a status a second), a
// lab bridge (`cutsim-viewer --lab`, a child process) that finds them from
// their streams and reads every one, and one instructor's page as WebSocket
// clients: the list and a grid of 8 watched sessions. Over a window it
// measures, per watched session, the bytes/s and frames/s the page
// receives, and the bridge's CPU (utime + stime from /proc, % of one core).
// Runs N = 8 and N = 32. JSON on stdout; exits 1 when a target is missed:
// every watched view ≥ 10 frames/s, the list shows all N sessions live,
// and the bridge ≤ 25 % of a core at 8 sessions and ≤ 50 % at 32.
//
//   lab_bench [--bin DIR] [--seconds 5] [--sessions 8,32] [--dds-domain 91]
#include <signal.h>
#include <sys/wait.h>
#include <unistd.h>

#include <algorithm>
#include <atomic>
#include <chrono>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <memory>
#include <sstream>
#include <stdexcept>
#include <string>
#include <thread>
#include <vector>

#include <CLI/CLI.hpp>
#include <fmt/format.h>

#include "common/core/clock.h"
#include "common/transport/dds.h"
#include "common/transport/mesh_publisher.h"
#include "tests/support/fake_mesh.h"
#include "tests/support/web_client.h"

namespace {

using namespace std::chrono_literals;

using namespace cutsim;  // NOLINT: a benchmark's own file

constexpr int kGridViews = 8;
constexpr double kFrameRate = 30.0;

/// utime + stime of `pid`, s.
double CpuSeconds(pid_t pid) {
  std::ifstream in("/proc/" + std::to_string(pid) + "/stat");
  std::string text((std::istreambuf_iterator<char>(in)), std::istreambuf_iterator<char>());
  const size_t close = text.rfind(')');
  if (close == std::string::npos) return 0;
  std::istringstream rest(text.substr(close + 2));
  std::string field;
  unsigned long long utime = 0, stime = 0;
  for (int i = 3; i <= 15 && rest >> field; ++i) {
    if (i == 14) utime = std::stoull(field);
    if (i == 15) stime = std::stoull(field);
  }
  return static_cast<double>(utime + stime) / static_cast<double>(::sysconf(_SC_CLK_TCK));
}

/// The lab bridge as a child process; its URL's port from its stdout.
struct Bridge {
  pid_t pid = -1;
  uint16_t port = 0;
  Bridge(const std::string& viewer, uint32_t domain) {
    int out[2];
    if (::pipe(out) != 0) throw std::runtime_error("pipe");
    pid = ::fork();
    if (pid == 0) {
      ::dup2(out[1], 1);
      ::close(out[0]);
      const std::string d = std::to_string(domain);
      ::execl(viewer.c_str(), viewer.c_str(), "--lab", "127.0.0.1:0", "--dds-domain", d.c_str(), "--log-level",
              "warn", static_cast<char*>(nullptr));
      ::_exit(127);
    }
    ::close(out[1]);
    std::string line;
    char c = 0;
    while (::read(out[0], &c, 1) == 1 && c != '\n') line += c;
    ::close(out[0]);
    const size_t colon = line.rfind(':');
    if (line.rfind("lab: ", 0) != 0 || colon == std::string::npos) {
      throw std::runtime_error("the lab bridge did not start (" + viewer + "): '" + line + "'");
    }
    port = static_cast<uint16_t>(std::stoi(line.substr(colon + 1)));
  }
  ~Bridge() {
    if (pid > 0) {
      ::kill(pid, SIGTERM);
      ::waitpid(pid, nullptr, 0);
    }
  }
};

/// One WebSocket client counting what it receives, on its own thread.
struct Watcher {
  std::atomic<uint64_t> bytes{0}, binary_frames{0}, texts{0};
  std::atomic<int> live_listed{0};
  std::atomic<bool> stop{false};
  std::string last_text;
  std::thread thread;
  test::WebSocketClient ws;

  void Start(uint16_t port, const std::string& target) {
    if (!ws.Open(port, target)) throw std::runtime_error("the lab bridge refused the WebSocket " + target);
    thread = std::thread([this] {
      while (!stop) {
        auto message = ws.Read();
        if (!message) break;
        bytes += message->first.size();
        if (message->second) {
          ++binary_frames;
        } else {
          ++texts;
          const std::string& text = message->first;
          size_t n = 0, at = 0;
          while ((at = text.find("\"live\":true", at)) != std::string::npos) ++n, ++at;
          live_listed = static_cast<int>(n);
        }
      }
    });
  }
  ~Watcher() {
    stop = true;
    ws.Shutdown();  // wakes the thread's blocking read
    if (thread.joinable()) thread.join();
  }
};

struct RunResult {
  int sessions = 0;
  double seconds = 0;
  double bridge_cpu_percent = 0;
  double list_bytes_per_s = 0;
  std::vector<double> view_bytes_per_s, view_fps;
  int live_listed = 0;
  int surface_vertices = 0;
};

RunResult RunOnce(const std::string& viewer, uint32_t domain, int sessions, double seconds) {
  transport::DdsParticipant participant(domain);
  std::vector<std::unique_ptr<transport::MeshStreamPublisher>> pubs;
  std::vector<support::FakeMesh> meshes;
  for (int i = 0; i < sessions; ++i) {
    pubs.push_back(std::make_unique<transport::MeshStreamPublisher>(participant, fmt::format("bay-{:02d}", i)));
    meshes.emplace_back(5, 0.03);
  }
  Bridge bridge(viewer, domain);
  std::atomic<bool> publishing{true};
  // The sessions, at 30 frames/s each, on this thread.
  std::thread publisher([&] {
    const auto period = static_cast<int64_t>(1e9 / kFrameRate);
    int64_t next = MonotonicNs(), last_status = 0;
    uint64_t frame = 0;
    while (publishing) {
      ++frame;
      const double t = static_cast<double>(frame) / kFrameRate;
      const bool status_due = next - last_status >= 1'000'000'000;
      if (status_due) last_status = next;
      for (int i = 0; i < sessions; ++i) {
        support::FakeMesh& m = meshes[static_cast<size_t>(i)];
        m.frame = frame;
        m.sim_time = t;
        m.Poke(Eigen::Vector3d(0.015 + 0.01 * std::sin(t + i), 0.015, 0.03), 0.012, 0.002);
        pubs[static_cast<size_t>(i)]->PublishFrame([&](transport::MeshFrame& f) { m.Fill(f); });
        if (status_due) {
          v1::SessionStatus st;
          st.set_frame(frame);
          st.set_sim_time(t);
          st.set_wall_time(t);
          st.set_scene("box");
          pubs[static_cast<size_t>(i)]->PublishStatus(st);
        }
      }
      next += period;
      SleepUntilNs(std::max(next, MonotonicNs()));
    }
  });
  RunResult r;
  r.sessions = sessions;
  {
    const support::FakeMesh m(5, 0.03);
    std::vector<int32_t> nodes(m.surface.data(), m.surface.data() + m.surface.size());
    std::sort(nodes.begin(), nodes.end());
    r.surface_vertices = static_cast<int>(std::unique(nodes.begin(), nodes.end()) - nodes.begin());
  }
  {
    Watcher list;
    list.Start(bridge.port, "/ws");
    std::vector<std::unique_ptr<Watcher>> views;
    for (int i = 0; i < std::min(sessions, kGridViews); ++i) {
      views.push_back(std::make_unique<Watcher>());
      views.back()->Start(bridge.port, fmt::format("/ws?session=bay-{:02d}", i));
    }
    // Warm up until every session is listed live and every view has frames
    // (the bridge reads a session once it is listed); 30 s at most.
    const int64_t give_up = MonotonicNs() + 30'000'000'000;
    while (MonotonicNs() < give_up &&
           (list.live_listed < sessions ||
            std::any_of(views.begin(), views.end(), [](const auto& v) { return v->binary_frames < 10; }))) {
      std::this_thread::sleep_for(50ms);
    }
    const double cpu0 = CpuSeconds(bridge.pid);
    const uint64_t list0 = list.bytes;
    std::vector<uint64_t> b0, f0;
    for (const auto& v : views) b0.push_back(v->bytes), f0.push_back(v->binary_frames);
    const int64_t t0 = MonotonicNs();
    std::this_thread::sleep_for(std::chrono::duration<double>(seconds));
    r.seconds = 1e-9 * static_cast<double>(MonotonicNs() - t0);
    r.bridge_cpu_percent = 100.0 * (CpuSeconds(bridge.pid) - cpu0) / r.seconds;
    r.list_bytes_per_s = static_cast<double>(list.bytes - list0) / r.seconds;
    for (size_t i = 0; i < views.size(); ++i) {
      r.view_bytes_per_s.push_back(static_cast<double>(views[i]->bytes - b0[i]) / r.seconds);
      r.view_fps.push_back(static_cast<double>(views[i]->binary_frames - f0[i]) / r.seconds);
    }
    r.live_listed = list.live_listed;
  }
  publishing = false;
  publisher.join();
  return r;
}

std::string Numbers(const std::vector<double>& v) {
  std::string out = "[";
  for (size_t i = 0; i < v.size(); ++i) out += fmt::format("{}{:.1f}", i ? ", " : "", v[i]);
  return out + "]";
}

}  // namespace

int main(int argc, char** argv) {
  CLI::App app{"lab_bench: the lab bridge's bytes/s per watched session and CPU at 8 and 32 sessions"};
  std::string bin = std::filesystem::canonical("/proc/self/exe").parent_path().string();
  double seconds = 5;
  std::vector<int> counts = {8, 32};
  uint32_t domain = 91;
  app.add_option("--bin", bin, "Folder of cutsim-viewer");
  app.add_option("--seconds", seconds, "Measured window per run, s")->check(CLI::Range(1.0, 600.0));
  app.add_option("--sessions", counts, "Session counts to run")->delimiter(',')->check(CLI::Range(1, 200));
  app.add_option("--dds-domain", domain, "DDS domain of the runs")->check(CLI::Range(0u, transport::kMaxDdsDomainId));
  CLI11_PARSE(app, argc, argv);
  const std::string viewer = bin + "/cutsim-viewer";
  std::string runs;
  std::vector<std::string> missed;
  double load = 0;
  std::ifstream("/proc/loadavg") >> load;
  for (const int n : counts) {
    const RunResult r = RunOnce(viewer, domain, n, seconds);
    const double min_fps = r.view_fps.empty() ? 0 : *std::min_element(r.view_fps.begin(), r.view_fps.end());
    double mean_bytes = 0;
    for (const double b : r.view_bytes_per_s) mean_bytes += b / static_cast<double>(r.view_bytes_per_s.size());
    const double cpu_target = n <= 8 ? 25.0 : 50.0;
    if (min_fps < 10) missed.push_back(fmt::format("{} sessions: a view at {:.1f} frames/s (< 10)", n, min_fps));
    if (r.live_listed != n) missed.push_back(fmt::format("{} sessions: {} listed live", n, r.live_listed));
    if (r.bridge_cpu_percent > cpu_target) {
      missed.push_back(fmt::format("{} sessions: bridge CPU {:.1f} % (> {:.0f} %)", n, r.bridge_cpu_percent, cpu_target));
    }
    runs += fmt::format(
        "{}    {{\"sessions\": {}, \"watched\": {}, \"seconds\": {:.2f}, \"live_listed\": {}, "
        "\"surface_vertices\": {}, \"bridge_cpu_percent_of_core\": {:.1f}, \"bridge_cpu_target\": {:.0f}, "
        "\"view_bytes_per_s_mean\": {:.0f}, \"view_bytes_per_s\": {}, \"view_fps_min\": {:.1f}, "
        "\"view_fps\": {}, \"list_bytes_per_s\": {:.0f}}}",
        runs.empty() ? "" : ",\n", n, r.view_fps.size(), r.seconds, r.live_listed, r.surface_vertices,
        r.bridge_cpu_percent, cpu_target, mean_bytes, Numbers(r.view_bytes_per_s), min_fps, Numbers(r.view_fps),
        r.list_bytes_per_s);
  }
  std::string missed_json;
  for (const std::string& m : missed) missed_json += fmt::format("{}\"{}\"", missed_json.empty() ? "" : ", ", m);
  std::printf("{\n  \"load_average_1min\": %.2f,\n  \"runs\": [\n%s\n  ],\n  \"missed\": [%s]\n}\n", load,
              runs.c_str(), missed_json.c_str());
  return missed.empty() ? 0 : 1;
}

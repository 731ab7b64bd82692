// The observer bridge under a connection flood: a child process runs the
// observers' server as `cutsim-viewer --serve` does (default caps, 1024
// descriptors); this process opens --idle idle connections to it from one
// peer (127.0.0.1) (with --reopen, re-opening any the server closes: a
// peer that churns rather than idles), and meanwhile fetches
// the page from another peer (127.0.0.2) every 100 ms. JSON on stdout: the
// page fetch times, the pages that failed, and the server's CPU over the
// flood (utime + stime from /proc). Exits 1 when a page takes more than
// 1 s or fails, or the server's CPU exceeds 10 % of a core.
//
//   bridge_flood_bench [--idle 1100] [--seconds 5] [--reopen]
#include <arpa/inet.h>
#include <fcntl.h>
#include <netinet/in.h>
#include <poll.h>
#include <signal.h>
#include <sys/resource.h>
#include <sys/socket.h>
#include <sys/wait.h>
#include <unistd.h>

#include <algorithm>
#include <chrono>
#include <cstdio>
#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <sstream>
#include <string>
#include <thread>
#include <vector>

#include <CLI/CLI.hpp>

#include "common/web/observer_server.h"

namespace {

using Clock = std::chrono::steady_clock;

/// A non-blocking connect from `from` to 127.0.0.1:port; −1 on failure.
int Connect(const char* from, uint16_t port, bool block) {
  const int fd = ::socket(AF_INET, SOCK_STREAM | (block ? 0 : SOCK_NONBLOCK), 0);
  if (fd < 0) return -1;
  sockaddr_in src{};
  src.sin_family = AF_INET;
  ::inet_pton(AF_INET, from, &src.sin_addr);
  sockaddr_in dst{};
  dst.sin_family = AF_INET;
  dst.sin_port = htons(port);
  dst.sin_addr.s_addr = htonl(INADDR_LOOPBACK);
  if (::bind(fd, reinterpret_cast<const sockaddr*>(&src), sizeof(src)) != 0 ||
      (::connect(fd, reinterpret_cast<const sockaddr*>(&dst), sizeof(dst)) != 0 && errno != EINPROGRESS)) {
    ::close(fd);
    return -1;
  }
  return fd;
}

/// GET / from 127.0.0.2 with a 2 s limit; the time in ms, or −1 on failure.
double FetchPage(uint16_t port) {
  const auto t0 = Clock::now();
  const int fd = Connect("127.0.0.2", port, true);
  if (fd < 0) return -1.0;
  timeval tv{2, 0};
  ::setsockopt(fd, SOL_SOCKET, SO_RCVTIMEO, &tv, sizeof(tv));
  const std::string req = "GET / HTTP/1.1\r\nHost: 127.0.0.1:" + std::to_string(port) + "\r\nConnection: close\r\n\r\n";
  std::string got;
  if (::send(fd, req.data(), req.size(), MSG_NOSIGNAL) == static_cast<ssize_t>(req.size())) {
    char buf[4096];
    ssize_t n = 0;
    while ((n = ::recv(fd, buf, sizeof(buf), 0)) > 0) got.append(buf, static_cast<size_t>(n));
  }
  ::close(fd);
  if (got.rfind("HTTP/1.1 200", 0) != 0 || got.find("flood page") == std::string::npos) return -1.0;
  return std::chrono::duration<double, std::milli>(Clock::now() - t0).count();
}

double CpuSeconds(pid_t pid) {
  std::ifstream in("/proc/" + std::to_string(pid) + "/stat");
  std::string line;
  std::getline(in, line);
  std::istringstream rest(line.substr(line.rfind(')') + 2));
  std::string field;
  double utime = 0;
  double stime = 0;
  for (int i = 3; i <= 15 && rest >> field; ++i) {
    if (i == 14) utime = std::stod(field);
    if (i == 15) stime = std::stod(field);
  }
  return (utime + stime) / static_cast<double>(::sysconf(_SC_CLK_TCK));
}

double Quantile(std::vector<double> v, double q) {
  if (v.empty()) return 0.0;
  std::sort(v.begin(), v.end());
  return v[static_cast<size_t>(q * static_cast<double>(v.size() - 1))];
}

}  // namespace

int main(int argc, char** argv) {
  CLI::App app{"The observer bridge under a flood of idle connections from one peer"};
  int idle = 1100;
  double seconds = 5.0;
  bool reopen = false;
  app.add_option("--idle", idle, "Idle connections from the flooding peer")->check(CLI::Range(1, 60000));
  app.add_option("--seconds", seconds, "How long the flood holds")->check(CLI::Range(1.0, 600.0));
  app.add_flag("--reopen", reopen, "Re-open the flood's connections the server closes");
  CLI11_PARSE(app, argc, argv);

  const auto dir = std::filesystem::temp_directory_path() / ("cutsim-flood-" + std::to_string(::getpid()));
  std::filesystem::create_directories(dir);
  std::ofstream(dir / "index.html") << "<html>flood page</html>";
  int port_pipe[2];
  int stop_pipe[2];
  if (::pipe(port_pipe) != 0 || ::pipe(stop_pipe) != 0) return 2;
  const pid_t server = ::fork();
  if (server == 0) {
    rlimit lim{};
    ::getrlimit(RLIMIT_NOFILE, &lim);
    lim.rlim_cur = std::min<rlim_t>(1024, lim.rlim_max);  // a default shell's limit
    ::setrlimit(RLIMIT_NOFILE, &lim);
    cutsim::web::ObserverServerOptions o;
    o.files = {{"/index.html", dir / "index.html"}};
    cutsim::web::ObserverServer s(o);
    const uint16_t port = s.port();
    (void)::write(port_pipe[1], &port, sizeof(port));
    char c = 0;
    (void)::read(stop_pipe[0], &c, 1);
    const auto st = s.stats();
    std::fprintf(stderr, "server: %d connections refused at accept, %llu accept backoffs\n",
                 static_cast<int>(st.web.refused_connections), static_cast<unsigned long long>(st.web.accept_backoffs));
    ::_exit(0);
  }
  uint16_t port = 0;
  if (::read(port_pipe[0], &port, sizeof(port)) != sizeof(port)) return 2;

  rlimit lim{};
  ::getrlimit(RLIMIT_NOFILE, &lim);
  lim.rlim_cur = std::min<rlim_t>(lim.rlim_max, static_cast<rlim_t>(idle) + 256);
  ::setrlimit(RLIMIT_NOFILE, &lim);
  std::vector<int> flood;
  for (int i = 0; i < idle; ++i) flood.push_back(Connect("127.0.0.1", port, false));
  std::this_thread::sleep_for(std::chrono::milliseconds(200));

  const double cpu0 = CpuSeconds(server);
  const auto t0 = Clock::now();
  std::vector<double> page_ms;
  int failed = 0;
  uint64_t reopened = 0;
  while (Clock::now() - t0 < std::chrono::duration<double>(seconds)) {
    // Re-open the flood's connections the server closed.
    for (int& fd : flood) {
      if (!reopen) break;
      pollfd p{fd, POLLIN, 0};
      if (fd < 0 || (::poll(&p, 1, 0) == 1 && (p.revents & (POLLIN | POLLHUP | POLLERR)) != 0)) {
        if (fd >= 0) ::close(fd);
        fd = Connect("127.0.0.1", port, false);
        ++reopened;
      }
    }
    const double ms = FetchPage(port);
    if (ms < 0) {
      ++failed;
    } else {
      page_ms.push_back(ms);
    }
    std::this_thread::sleep_for(std::chrono::milliseconds(100));
  }
  const double wall = std::chrono::duration<double>(Clock::now() - t0).count();
  const double cpu_percent = 100.0 * (CpuSeconds(server) - cpu0) / wall;
  for (const int fd : flood) {
    if (fd >= 0) ::close(fd);
  }
  (void)::write(stop_pipe[1], "x", 1);
  ::waitpid(server, nullptr, 0);
  std::filesystem::remove_all(dir);

  const double max_ms = page_ms.empty() ? 0.0 : *std::max_element(page_ms.begin(), page_ms.end());
  const bool ok = failed == 0 && max_ms <= 1000.0 && cpu_percent < 10.0;
  std::printf(
      "{\"bench\":\"bridge_flood\",\"idle_connections\":%d,\"reopen\":%s,\"seconds\":%.1f,\"flood_reconnects\":%llu,"
      "\"pages\":%zu,\"pages_failed\":%d,\"page_p50_ms\":%.2f,\"page_max_ms\":%.2f,"
      "\"server_cpu_percent_of_core\":%.2f,\"targets\":{\"page_max_ms\":1000,\"server_cpu_percent\":10},"
      "\"ok\":%s}\n",
      idle, reopen ? "true" : "false", wall, static_cast<unsigned long long>(reopened), page_ms.size(), failed, Quantile(page_ms, 0.5), max_ms,
      cpu_percent, ok ? "true" : "false");
  return ok ? 0 : 1;
}

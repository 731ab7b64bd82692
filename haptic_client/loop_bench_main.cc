// cutsim-haptic-loop-bench: the reference for the haptic loop's timing. Runs
// a bare 1 kHz clock_nanosleep (TIMER_ABSTIME) loop that does nothing else,
// with the same real-time setup as cutsim-haptic, and prints the same period /
// jitter / lateness quantiles as cutsim-haptic's JSON summary, so the two can
// be compared under the same load. `--hog` adds a busy-loop thread (a
// stand-in for the server's physics thread loading the other core).
#include <atomic>
#include <cmath>
#include <cstdio>
#include <string>
#include <thread>

#include <CLI/CLI.hpp>
#include <fmt/format.h>

#include "common/core/clock.h"
#include "common/core/log.h"
#include "haptic_client/haptic_app.h"
#include "haptic_client/loop_stats.h"

int main(int argc, char** argv) {
  double seconds = 20.0;
  double rate = 1000.0;
  bool hog = false;
  bool no_rt = false;
  CLI::App app{"Bare clock_nanosleep loop timing (reference for cutsim-haptic)"};
  app.add_option("--seconds", seconds, "Run time, s")->capture_default_str();
  app.add_option("--rate", rate, "Loop rate, Hz")->capture_default_str();
  app.add_flag("--hog", hog, "Run a busy-loop thread alongside");
  app.add_flag("--no-rt", no_rt, "Do not try SCHED_FIFO and mlockall");
  CLI11_PARSE(app, argc, argv);
  cutsim::InitLogging("cutsim-haptic-loop-bench", "info");
  using cutsim::haptic_client::Histogram;

  std::atomic<bool> stop{false};
  std::thread hog_thread;
  if (hog) {
    hog_thread = std::thread([&] {
      volatile double x = 1.0;
      while (!stop.load(std::memory_order_relaxed)) x = std::sqrt(x + 1.0);
    });
  }
  cutsim::haptic_client::RealtimeStatus rt;
  if (!no_rt) rt = cutsim::haptic_client::TryEnableRealtime(80);

  Histogram period_us(1.0, 20000), jitter_us(1.0, 20000), lateness_us(1.0, 20000);
  const int64_t period_ns = std::llround(1e9 / rate);
  const int64_t t0 = cutsim::MonotonicNs() + period_ns;
  const int64_t end = t0 + std::llround(seconds * 1e9);
  int64_t deadline = t0;
  int64_t prev = 0;
  uint64_t missed = 0, ticks = 0;
  while (true) {
    cutsim::SleepUntilNs(deadline);
    const int64_t now = cutsim::MonotonicNs();
    lateness_us.Add(1e-3 * static_cast<double>(now - deadline));
    if (prev != 0) {
      const double p = 1e-3 * static_cast<double>(now - prev);
      period_us.Add(p);
      jitter_us.Add(std::abs(p - 1e-3 * static_cast<double>(period_ns)));
    }
    prev = now;
    ++ticks;
    if (now >= end) break;
    deadline += period_ns;
    const int64_t after = cutsim::MonotonicNs();
    if (after > deadline) {
      const int64_t behind = (after - deadline) / period_ns + 1;
      missed += static_cast<uint64_t>(behind);
      deadline += behind * period_ns;
    }
  }
  stop.store(true);
  if (hog_thread.joinable()) hog_thread.join();
  auto q = [](const Histogram& h) {
    return fmt::format(R"({{"p50":{:.3f},"p99":{:.3f},"max":{:.3f},"mean":{:.3f},"n":{}}})", h.Quantile(0.5),
                       h.Quantile(0.99), h.max(), h.mean(), h.count());
  };
  std::printf("%s\n", fmt::format(R"({{"kind":"bare_loop_stats","ticks":{},"missed_deadlines":{},"sched_fifo":{},)"
                                  R"("mlocked":{},"hog":{},"period_us":{},"jitter_us":{},"lateness_us":{}}})",
                                  ticks, missed, rt.fifo, rt.mlocked, hog, q(period_us), q(jitter_us),
                                  q(lateness_us))
                          .c_str());
  return 0;
}

// cutsim-haptic-loop-bench: the reference for the haptic loop's timing. Runs
// a bare 1 kHz clock_nanosleep (TIMER_ABSTIME) loop that does nothing else,
// with the same real-time setup as cutsim-haptic, and prints the same period /
// jitter / lateness quantiles as cutsim-haptic's JSON summary, so the two can
// be compared under the same load. `--hog` adds a busy-loop thread (a
// stand-in for the server's physics thread loading the other core).
// `--devices` instead measures the loop with each device (device_bench.h):
// jitter per built-in device and the plugin example, and the cost of a
// plugin call against a built-in one.
#include <atomic>
#include <cmath>
#include <cstdio>
#include <filesystem>
#include <string>
#include <thread>

#include <CLI/CLI.hpp>

#include "common/core/clock.h"
#include "common/core/install_paths.h"
#include "common/core/log.h"
#include "common/transport/realtime_thread.h"
#include "common/transport/report_json.h"
#include "cutsim/v1/report.pb.h"
#include "haptic_client/device_bench.h"
#include "haptic_client/loop_stats.h"
#include "haptic_client/plugin_loader.h"

int main(int argc, char** argv) {
  double seconds = 20.0;
  double rate = 1000.0;
  bool hog = false;
  bool no_rt = false;
  bool devices = false;
  cutsim::haptic_client::DeviceBenchOptions device_options;
  device_options.plugin_dir = cutsim::PluginDir();
  device_options.work_dir = std::filesystem::temp_directory_path();
  CLI::App app{"Bare clock_nanosleep loop timing (reference for cutsim-haptic), or the loop per device"};
  app.add_option("--seconds", seconds, "Run time, s")->capture_default_str();
  app.add_option("--rate", rate, "Loop rate, Hz")->capture_default_str();
  app.add_flag("--hog", hog, "Run a busy-loop thread alongside");
  app.add_flag("--no-rt", no_rt, "Do not try SCHED_FIFO and mlockall");
  app.add_flag("--devices", devices, "Loop jitter and call cost per device (--seconds each) instead");
  app.add_option("--calls", device_options.calls, "--devices: ticks of the call-cost loop")->capture_default_str();
  app.add_option("--device-dir", device_options.plugin_dir, "--devices: folder of the example plugin");
  CLI11_PARSE(app, argc, argv);
  cutsim::InitLogging("cutsim-haptic-loop-bench", "info");
  if (devices) {
    if (!no_rt) (void)cutsim::transport::TryEnableRealtime(cutsim::transport::kHapticLoopPriority, "device loop");
    device_options.seconds = seconds;
    device_options.rate = rate;
    std::printf("%s\n", cutsim::haptic_client::RunDeviceBench(device_options).c_str());
    return 0;
  }
  using cutsim::haptic_client::Histogram;

  std::atomic<bool> stop{false};
  std::thread hog_thread;
  if (hog) {
    hog_thread = std::thread([&] {
      volatile double x = 1.0;
      while (!stop.load(std::memory_order_relaxed)) x = std::sqrt(x + 1.0);
    });
  }
  cutsim::transport::RealtimeStatus rt;
  if (!no_rt) rt = cutsim::transport::TryEnableRealtime(cutsim::transport::kHapticLoopPriority, "bare loop");

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
  using cutsim::haptic_client::QuantilesReport;
  using cutsim::transport::ReportCount;
  cutsim::v1::BareLoopStats report;
  report.set_kind("bare_loop_stats");
  report.set_ticks(ReportCount(ticks));
  report.set_missed_deadlines(ReportCount(missed));
  report.set_sched_fifo(rt.fifo);
  report.set_mlocked(rt.mlocked);
  report.set_hog(hog);
  *report.mutable_period_us() = QuantilesReport(period_us);
  *report.mutable_jitter_us() = QuantilesReport(jitter_us);
  *report.mutable_lateness_us() = QuantilesReport(lateness_us);
  std::printf("%s\n", cutsim::transport::ReportJson(report).c_str());
  return 0;
}

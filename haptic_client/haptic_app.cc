#include "haptic_client/haptic_app.h"

#include <pthread.h>
#include <sched.h>
#include <sys/mman.h>

#include <array>
#include <atomic>
#include <cerrno>
#include <chrono>
#include <cmath>
#include <csignal>
#include <cstdio>
#include <cstring>
#include <filesystem>
#include <memory>
#include <optional>
#include <thread>
#include <vector>

#include <fmt/format.h>

#include "common/core/clock.h"
#include "common/core/error.h"
#include "common/core/log.h"
#include "common/haptics/haptic_renderer.h"
#include "common/haptics/tool_path.h"
#include "common/transport/channels.h"
#include "common/transport/haptic_link.h"
#include "common/transport/lcm_bus.h"
#include "common/transport/realtime_thread.h"
#include "common/transport/tool_auth.h"
#include "haptic_client/loop_stats.h"
#include "haptic_client/virtual_devices.h"

namespace cutsim::haptic_client {
namespace {

std::atomic<bool> g_stop{false};
extern "C" void OnStopSignal(int /*sig*/) { g_stop.store(true); }

/// One CSV row, written by the servo loop into a preallocated ring.
struct CsvRow {
  double t;                 // s since the loop started
  double x, y, z;           // m
  double fx, fy, fz;        // N
  double model_age_ms;      // ms since the model in use arrived (−1: none yet)
  double period_us;         // µs since the previous tick
  double lateness_us;       // µs past the deadline at wake-up
  double watchdog_gain;     // 0..1
  int phase;                // 0 buffer model, 1 cut decay, 2 blend back
  uint64_t cuts;            // cut counter of the model in use
  int contact;              // model in use reports contact
  double energy_j;          // passivity observer E_obs, J
  double dissipated_j;      // passivity controller Σ, J
  uint64_t model_seq;       // seq of the model in use
  uint64_t epoch;           // server stream epoch
};

/// Single-producer (servo loop) single-consumer (writer thread) ring.
class CsvRing {
 public:
  explicit CsvRing(size_t capacity_pow2) : rows_(capacity_pow2), mask_(capacity_pow2 - 1) {}
  bool Push(const CsvRow& row) noexcept {
    const uint64_t head = head_.load(std::memory_order_relaxed);
    if (head - tail_.load(std::memory_order_acquire) > mask_) {
      ++dropped_;
      return false;
    }
    rows_[head & mask_] = row;
    head_.store(head + 1, std::memory_order_release);
    return true;
  }
  template <class Fn>
  size_t Drain(Fn&& fn) {
    const uint64_t head = head_.load(std::memory_order_acquire);
    uint64_t tail = tail_.load(std::memory_order_relaxed);
    const size_t n = head - tail;
    for (; tail != head; ++tail) fn(rows_[tail & mask_]);
    tail_.store(tail, std::memory_order_release);
    return n;
  }
  [[nodiscard]] uint64_t dropped() const { return dropped_; }

 private:
  std::vector<CsvRow> rows_;
  uint64_t mask_;
  std::atomic<uint64_t> head_{0};
  std::atomic<uint64_t> tail_{0};
  uint64_t dropped_ = 0;  // servo-loop only
};

/// Writes the ring to `path` from its own thread; the file appears under its
/// name only when complete (temp file, then rename).
class CsvWriter {
 public:
  CsvWriter(std::string path, CsvRing& ring) : path_(std::move(path)), ring_(ring) {
    const std::filesystem::path p(path_);
    if (p.has_parent_path()) std::filesystem::create_directories(p.parent_path());
    tmp_ = path_ + ".tmp";
    file_ = std::fopen(tmp_.c_str(), "w");
    if (file_ == nullptr) ThrowFileError(path_, fmt::format("cannot write the CSV: {}", std::strerror(errno)));
    std::fputs("t_s,x_m,y_m,z_m,fx_n,fy_n,fz_n,f_n,model_age_ms,period_us,lateness_us,watchdog_gain,"
               "phase,cuts,contact,energy_j,dissipated_j,model_seq,epoch\n",
               file_);
    thread_ = std::thread([this] {
      pthread_setname_np(pthread_self(), "cutsim-csv");
      while (!stop_.load()) {
        Flush();
        std::this_thread::sleep_for(std::chrono::milliseconds(50));
      }
      Flush();
    });
  }
  ~CsvWriter() { Finish(); }
  CsvWriter(const CsvWriter&) = delete;
  CsvWriter& operator=(const CsvWriter&) = delete;

  /// Joins the thread, closes and renames. Returns rows written.
  uint64_t Finish() {
    if (thread_.joinable()) {
      stop_.store(true);
      thread_.join();
    }
    if (file_ != nullptr) {
      const bool ok = std::fflush(file_) == 0 && !std::ferror(file_);
      std::fclose(file_);
      file_ = nullptr;
      std::error_code ec;
      if (ok) std::filesystem::rename(tmp_, path_, ec);
      if (!ok || ec) Log().error("could not complete the CSV {} (left {} in place)", path_, tmp_);
    }
    return rows_;
  }

 private:
  void Flush() {
    rows_ += ring_.Drain([&](const CsvRow& r) {
      const double f = std::sqrt(r.fx * r.fx + r.fy * r.fy + r.fz * r.fz);
      std::fprintf(file_, "%.6f,%.7g,%.7g,%.7g,%.6g,%.6g,%.6g,%.6g,%.4f,%.2f,%.2f,%.5f,%d,%llu,%d,%.6g,%.6g,%llu,%llu\n",
                   r.t, r.x, r.y, r.z, r.fx, r.fy, r.fz, f, r.model_age_ms, r.period_us, r.lateness_us,
                   r.watchdog_gain, r.phase, static_cast<unsigned long long>(r.cuts), r.contact, r.energy_j,
                   r.dissipated_j, static_cast<unsigned long long>(r.model_seq),
                   static_cast<unsigned long long>(r.epoch));
    });
  }

  std::string path_;
  std::string tmp_;
  CsvRing& ring_;
  std::FILE* file_ = nullptr;
  uint64_t rows_ = 0;
  std::atomic<bool> stop_{false};
  std::thread thread_;
};

std::unique_ptr<HapticDevice> MakeDevice(const HapticAppOptions& o) {
  DeviceInfo info;
  if (o.device == "scripted") {
    info.name = "scripted";
    return std::make_unique<ScriptedDevice>(haptics::ToolPath::Read(o.path), info);
  }
  info.name = "replay";
  const std::string channel =
      o.log_channel.empty() ? transport::LcmChannelName(o.session, transport::LcmChannel::kTool) : o.log_channel;
  return std::make_unique<ReplayDevice>(o.log, channel, info);
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

std::string Quantiles(const Histogram& h, double scale) {
  return fmt::format(R"({{"p50":{:.3f},"p99":{:.3f},"max":{:.3f},"mean":{:.3f},"n":{}}})", scale * h.Quantile(0.5),
                     scale * h.Quantile(0.99), scale * h.max(), scale * h.mean(), h.count());
}

/// Pre-touches `bytes` of stack so the loop never faults a new stack page.
void PrefaultStack() {
  constexpr size_t kBytes = 256 * 1024;
  [[maybe_unused]] volatile unsigned char buffer[kBytes];
  for (size_t i = 0; i < kBytes; i += 4096) buffer[i] = 0;
}

}  // namespace

RealtimeStatus TryEnableRealtime(int priority) {
  RealtimeStatus status;
  if (mlockall(MCL_CURRENT | MCL_FUTURE) == 0) {
    status.mlocked = true;
  } else {
    Log().warn("mlockall failed ({}): memory is not locked, a page fault can stall the haptic loop "
               "(raise RLIMIT_MEMLOCK, e.g. `ulimit -l unlimited`, or grant CAP_IPC_LOCK)",
               std::strerror(errno));
  }
  sched_param param{};
  param.sched_priority = priority;
  const int rc = pthread_setschedparam(pthread_self(), SCHED_FIFO, &param);
  if (rc == 0) {
    status.fifo = true;
  } else {
    Log().warn("SCHED_FIFO priority {} not permitted ({}): the haptic loop runs as a normal thread and "
               "other load can delay it (grant CAP_SYS_NICE or an rtprio limit in "
               "/etc/security/limits.conf, or run with --no-rt to silence this)",
               priority, std::strerror(rc));
  }
  return status;
}

void ValidateOptions(const HapticAppOptions& o) {
  transport::ValidateSessionName(o.session, "--session");
  if (o.device != "scripted" && o.device != "replay") {
    ThrowInputError(SourceRef{.field = "--device"}, fmt::format("unknown device \"{}\" (scripted or replay)", o.device));
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
}

int RunHapticApp(const HapticAppOptions& o) {
  ValidateOptions(o);
  std::unique_ptr<HapticDevice> device = MakeDevice(o);
  haptics::HapticRenderer renderer(MakeConfig(o, device->info()));

  transport::HapticLinkOptions link_options;
  if (o.fault_direction != "model") link_options.publish_faults = o.faults;
  if (o.fault_direction != "tool") {
    link_options.receive_faults = o.faults;
    link_options.receive_faults.seed = o.faults.seed + 1;  // independent fates per direction
  }
  if (o.faults.active()) Log().info("fault injection ({}): {}", o.fault_direction, transport::Describe(o.faults));
  // Access control: sign every tool message when the session has a key.
  std::unique_ptr<transport::HmacToolAuthenticator> authenticator;
  if (const auto key = transport::LoadSessionKey(o.key_file)) {
    authenticator = std::make_unique<transport::HmacToolAuthenticator>(*key, o.session);
    link_options.authenticator = authenticator.get();
    Log().info("session '{}': tool messages are signed (HMAC-SHA256, key from {})", o.session,
               o.key_file.empty() ? std::string("$") + transport::kSessionKeyEnv : o.key_file);
  } else {
    Log().warn("session '{}': no session key (--key-file or ${}): tool messages are NOT signed; "
               "a server with a key will ignore them",
               o.session, transport::kSessionKeyEnv);
  }
  // The LCM threads run SCHED_FIFO below the servo loop, so a pose is sent
  // and a model taken in while other load runs. LCM's own udpm receive
  // thread starts on the first subscription and inherits the scope's policy.
  const int lcm_priority = o.realtime ? std::min(transport::kLcmThreadPriority, o.rt_priority - 1) : 0;
  std::optional<transport::ScopedThreadFifo> lcm_scope;
  if (lcm_priority > 0) lcm_scope.emplace(lcm_priority);
  transport::LcmBus bus(o.lcm_url);
  transport::HapticClientLink link(bus, o.session, link_options);
  lcm_scope.reset();

  // ---- Preallocate everything the loop touches. --------------------------
  const int64_t period_ns = std::llround(1e9 / o.rate);
  const int tool_every = std::max(1, static_cast<int>(std::lround(o.rate / o.tool_rate)));
  Histogram period_us(1.0, 20000);     // 1 µs bins to 20 ms
  Histogram jitter_us(1.0, 20000);     // |period − nominal|
  Histogram lateness_us(1.0, 20000);   // wake-up past the deadline
  Histogram model_age_ms(0.01, 200000);  // 10 µs bins to 2 s
  Histogram latency_ms(0.01, 200000);    // device read of a pose → model computed from it received (LCM thread)
  Histogram use_latency_ms(0.01, 200000);  // the same, to the first tick that renders that model
  constexpr size_t kSendRing = 4096;
  std::array<int64_t, kSendRing> send_ns{};
  std::array<uint64_t, kSendRing> send_seq{};
  const bool write_csv = !o.csv.empty() && o.csv != "-";
  CsvRing ring(size_t{1} << 16);  // 65 s at 1 kHz; the writer drains every 50 ms
  std::unique_ptr<CsvWriter> writer;
  if (write_csv) writer = std::make_unique<CsvWriter>(o.csv, ring);

  std::signal(SIGINT, OnStopSignal);
  std::signal(SIGTERM, OnStopSignal);

  // Helper threads first (they inherit SCHED_OTHER), then our priority.
  link.Start(100, lcm_priority);
  RealtimeStatus rt;
  if (o.realtime) rt = TryEnableRealtime(o.rt_priority);
  PrefaultStack();

  Log().info("haptic loop: {} Hz, tool poses at {} Hz, session {}, LCM {}, device {}", o.rate,
             o.rate / tool_every, o.session, o.lcm_url, device->info().name);

  // ---- The servo loop: no allocation, logging, throwing or blocking. ------
  uint64_t ticks = 0;
  uint64_t missed = 0;
  uint64_t last_epoch = 0;
  bool have_model = false;
  transport::ReceivedModel received;
  DeviceState state;
  const char* end_reason = "device done";
  const int64_t t0 = MonotonicNs() + period_ns;
  const int64_t end_ns = o.duration > 0.0 ? t0 + std::llround(o.duration * 1e9) : INT64_MAX;
  device->Start(t0);
  int64_t deadline = t0;
  int64_t prev_wake = 0;
  for (;;) {
    SleepUntilNs(deadline);
    const int64_t now = MonotonicNs();
    const double lateness = 1e-3 * static_cast<double>(now - deadline);
    const double dt = prev_wake == 0 ? 1e-9 * static_cast<double>(period_ns) : 1e-9 * static_cast<double>(now - prev_wake);
    if (prev_wake != 0) {
      const double p = 1e-3 * static_cast<double>(now - prev_wake);
      period_us.Add(p);
      jitter_us.Add(std::abs(p - 1e-3 * static_cast<double>(period_ns)));
    }
    lateness_us.Add(lateness);
    prev_wake = now;

    device->Read(now, &state);
    if (ticks % static_cast<uint64_t>(tool_every) == 0) {
      transport::ToolSample sample;
      sample.stamp_ns = now;
      sample.tip = state.position;
      sample.blade_dir = state.blade_dir;
      sample.velocity = state.velocity;
      sample.buttons = state.buttons;
      const uint64_t seq = link.PublishTool(sample);
      send_ns[seq % kSendRing] = now;
      send_seq[seq % kSendRing] = seq;
    }
    if (link.TakeModel(&received)) {
      if (have_model && received.epoch != last_epoch) renderer.Reset();  // the server restarted
      last_epoch = received.epoch;
      have_model = true;
      renderer.SetModel(received.model, received.receive_ns);
      const uint64_t ts = received.tool_seq;
      if (ts != 0 && send_seq[ts % kSendRing] == ts) {
        latency_ms.Add(1e-6 * static_cast<double>(received.receive_ns - send_ns[ts % kSendRing]));
        use_latency_ms.Add(1e-6 * static_cast<double>(now - send_ns[ts % kSendRing]));
      }
    }
    const Eigen::Vector3d force = renderer.Tick(state.position, state.velocity, now, dt);
    device->SetForce(force);

    const double age_ms = have_model ? 1e-6 * static_cast<double>(now - received.receive_ns) : -1.0;
    if (have_model) model_age_ms.Add(age_ms);
    if (write_csv) {
      const auto& st = renderer.stats();
      ring.Push(CsvRow{.t = 1e-9 * static_cast<double>(now - t0),
                       .x = state.position.x(), .y = state.position.y(), .z = state.position.z(),
                       .fx = force.x(), .fy = force.y(), .fz = force.z(),
                       .model_age_ms = age_ms,
                       .period_us = 1e6 * dt,
                       .lateness_us = lateness,
                       .watchdog_gain = renderer.watchdog_gain(),
                       .phase = static_cast<int>(renderer.phase()),
                       .cuts = have_model ? received.model.cut.cuts : 0,
                       .contact = have_model && received.model.contact ? 1 : 0,
                       .energy_j = st.observed_energy,
                       .dissipated_j = st.passivity_dissipated,
                       .model_seq = have_model ? received.model.seq : 0,
                       .epoch = received.epoch});
    }
    ++ticks;

    if (state.done) break;
    if (now >= end_ns) {
      end_reason = "duration";
      break;
    }
    if (g_stop.load(std::memory_order_relaxed)) {
      end_reason = "signal";
      break;
    }
    deadline += period_ns;
    const int64_t after = MonotonicNs();
    if (after > deadline) {
      // Woke (or ran) past the next deadline: count it and skip ahead.
      const int64_t behind = (after - deadline) / period_ns + 1;
      missed += static_cast<uint64_t>(behind);
      deadline += behind * period_ns;
    }
  }
  // ---- After the loop. ------------------------------------------------------
  device->SetForce(Eigen::Vector3d::Zero());
  device->Stop();
  if (rt.fifo) {
    sched_param normal{};
    pthread_setschedparam(pthread_self(), SCHED_OTHER, &normal);
  }
  link.Stop();
  const uint64_t csv_rows = writer ? writer->Finish() : 0;

  const auto& rs = renderer.stats();
  const transport::HapticClientLinkStats ls = link.stats();
  Log().info("haptic loop ended ({}): {} ticks, {} missed deadlines, period p50 {:.1f} µs p99 {:.1f} µs max "
             "{:.1f} µs, jitter p99 {:.1f} µs",
             end_reason, ticks, missed, period_us.Quantile(0.5), period_us.Quantile(0.99), period_us.max(),
             jitter_us.Quantile(0.99));
  Log().info("models: {} accepted, {} rejected, {} stale by the renderer; link: {} received, {} garbage, {} "
             "foreign session, {} out of order, {} duplicate, {} malformed, {} server restarts",
             rs.models_accepted, rs.models_rejected, rs.models_stale, ls.models_received, ls.decode_errors,
             ls.foreign_session, ls.stale, ls.duplicate, ls.malformed, ls.restarts);
  Log().info("watchdog trips {}, cut decays {}, passivity dissipated {:.6f} J (E_obs {:.6f} J, min {:.6f} J), "
             "model age p99 {:.2f} ms, pose-to-model p99 {:.2f} ms",
             rs.watchdog_trips, rs.cut_decays_started, rs.passivity_dissipated, rs.observed_energy,
             rs.min_observed_energy, model_age_ms.Quantile(0.99), latency_ms.Quantile(0.99));
  if (ring.dropped() > 0) Log().warn("{} CSV rows dropped (writer too slow)", ring.dropped());

  const transport::FaultStats fp = link.publish_fault_stats();
  const transport::FaultStats fr = link.receive_fault_stats();
  std::string json = fmt::format(
      R"({{"kind":"haptic_stats","end":"{}","ticks":{},"missed_deadlines":{},"rate_hz":{},"sched_fifo":{},"mlocked":{},)"
      R"("period_us":{},"jitter_us":{},"lateness_us":{},"model_age_ms":{},"pose_to_model_ms":{},"pose_to_use_ms":{},)",
      end_reason, ticks, missed, o.rate, rt.fifo, rt.mlocked, Quantiles(period_us, 1.0), Quantiles(jitter_us, 1.0),
      Quantiles(lateness_us, 1.0), Quantiles(model_age_ms, 1.0), Quantiles(latency_ms, 1.0),
      Quantiles(use_latency_ms, 1.0));
  json += fmt::format(
      R"("models_accepted":{},"models_rejected":{},"models_stale":{},"watchdog_trips":{},"cut_decays":{},)"
      R"("non_finite_inputs":{},"passivity_dissipated_j":{:.9g},"observed_energy_j":{:.9g},"min_observed_energy_j":{:.9g},)"
      R"("max_force_n":{:.6g},"max_force_step_n":{:.6g},)",
      rs.models_accepted, rs.models_rejected, rs.models_stale, rs.watchdog_trips, rs.cut_decays_started,
      rs.non_finite_inputs, rs.passivity_dissipated, rs.observed_energy, rs.min_observed_energy, rs.max_force,
      rs.max_force_step);
  json += fmt::format(
      R"("link":{{"tools_written":{},"tools_published":{},"tools_coalesced":{},"tools_not_sent":{},"models_received":{},)"
      R"("models_superseded":{},"decode_errors":{},"foreign_session":{},"stale":{},"duplicate":{},"malformed":{},)"
      R"("restarts":{},"accepted":{}}},"faults":{{"tool_dropped":{},"tool_duplicated":{},"model_dropped":{},)"
      R"("model_duplicated":{},"model_reordered":{}}},"csv_rows":{},"csv_dropped":{}}})",
      ls.tools_written, ls.tools_published, ls.tools_coalesced, ls.tools_not_sent, ls.models_received,
      ls.models_superseded, ls.decode_errors, ls.foreign_session, ls.stale, ls.duplicate, ls.malformed, ls.restarts,
      ls.accepted, fp.dropped, fp.duplicated, fr.dropped, fr.duplicated, fr.reordered, csv_rows, ring.dropped());
  std::fputs(json.c_str(), stdout);
  std::fputc('\n', stdout);
  std::fflush(stdout);
  return 0;
}

}  // namespace cutsim::haptic_client

#include "haptic_client/threaded_device.h"

#include <pthread.h>
#include <sched.h>

#include <algorithm>
#include <chrono>
#include <cmath>
#include <utility>

#include <fmt/format.h>

#include "common/core/clock.h"
#include "common/core/error.h"
#include "common/core/log.h"

namespace cutsim::haptic_client {
namespace {

/// A tick's force for the device thread: the tick that sent it, its time,
/// and the model's cut state for a device that shows it.
struct Command {
  int64_t tick = -1;
  int64_t now_ns = 0;
  Eigen::Vector3d force = Eigen::Vector3d::Zero();
  uint64_t cuts = 0;
  bool contact = false;
};

/// A reading and the tick whose command it followed (-1: Start's).
struct Reading {
  int64_t tick = -1;
  DeviceState state;
};

/// Under SCHED_FIFO, one priority below the thread that created this one
/// (the servo loop), so a device that spins never starves the loop.
void RunBelowTheLoop() {
  int policy = 0;
  sched_param param{};
  if (pthread_getschedparam(pthread_self(), &policy, &param) != 0) return;
  if (policy != SCHED_FIFO || param.sched_priority <= 1) return;
  --param.sched_priority;
  (void)pthread_setschedparam(pthread_self(), SCHED_FIFO, &param);
}

}  // namespace

/// What the loop and the device thread share. Held by both, so a device
/// thread left inside the device keeps the device (and its library) alive
/// until it returns.
struct ThreadedDevice::Shared {
  std::unique_ptr<HapticDevice> device;
  transport::Mailbox<Command> commands;  // loop → device thread
  transport::Mailbox<Reading> readings;  // device thread → loop
  std::atomic<uint32_t> wake{0};         // bumped by every command; the thread waits on it
  std::atomic<bool> quit{false};
  std::atomic<bool> done{false};         // the device thread left its loop
  std::atomic<uint64_t> cycles{0};
};

ThreadedDevice::ThreadedDevice(std::unique_ptr<HapticDevice> device, const ThreadedDeviceOptions& options)
    : shared_(std::make_shared<Shared>()), options_(options) {
  CUTSIM_CHECK(device != nullptr, "ThreadedDevice: no device");
  if (options.late_ticks < 1 || options.stuck_ticks <= options.late_ticks) {
    ThrowInputError(SourceRef{.field = "device deadline"},
                    fmt::format("late after {} ticks, stuck after {}: need 1 ≤ late < stuck", options.late_ticks,
                                options.stuck_ticks));
  }
  for (const auto& [field, seconds] : {std::pair{"device stop grace", options.stop_grace_s},
                                       std::pair{"device start timeout", options.start_timeout_s}}) {
    if (!(std::isfinite(seconds) && seconds > 0.0 && seconds <= 10.0)) {
      ThrowInputError(SourceRef{.field = field}, fmt::format("{} s is out of range (0, 10] s", seconds));
    }
  }
  info_ = device->info();
  shared_->device = std::move(device);
}

ThreadedDevice::~ThreadedDevice() {
  Stop();
  if (thread_.joinable()) thread_.join();
}

const HapticDevice& ThreadedDevice::device() const { return *shared_->device; }

void ThreadedDevice::Start(int64_t start_ns) {
  now_ns_ = start_ns;
  shared_->device->Start(start_ns);
  thread_ = std::thread([s = shared_, start_ns] { DeviceThread(s, start_ns); });
  started_ = true;
  // The first reading is the device thread's too: wait for it, but only
  // so long, so a device blocked from the start cannot hold the station.
  const int64_t until = MonotonicNs() + static_cast<int64_t>(std::llround(options_.start_timeout_s * 1e9));
  while (shared_->cycles.load(std::memory_order_acquire) == 0 && MonotonicNs() < until) {
    std::this_thread::sleep_for(std::chrono::microseconds(100));
  }
}

void ThreadedDevice::Read(int64_t now_ns, DeviceState* state) noexcept {
  now_ns_ = now_ns;
  transport::Mailbox<Reading>& readings = shared_->readings;
  if (readings.TakeFresh()) {
    last_ = readings.front().state;
    have_reading_ = true;
  }
  // Ticks between the newest command sent and the one this reading
  // followed: 0 when the device kept up. Before any reading, every tick
  // since the start, and the state (no pose yet) is late.
  const int64_t lag = (ticks_ - 1) - (have_reading_ ? readings.front().tick : -1);
  const bool late = !have_reading_ || lag > options_.late_ticks;
  *state = last_;
  state->late = late;
  state->stuck = lag >= options_.stuck_ticks;
  stats_.max_lag_ticks = std::max(stats_.max_lag_ticks, lag);
  if (late) {
    ++stats_.late_ticks;
    if (!was_late_) ++stats_.late_episodes;
  }
  was_late_ = late;
  stats_.stuck = stats_.stuck || state->stuck;
}

void ThreadedDevice::SetForce(const Eigen::Vector3d& force) noexcept {
  Command& c = shared_->commands.back();
  c.tick = ticks_++;
  c.now_ns = now_ns_;
  c.force = force;
  c.cuts = cuts_;
  c.contact = contact_;
  shared_->commands.Publish();
  // A futex wake when the thread waits, nothing when it is busy: never blocks.
  shared_->wake.fetch_add(1, std::memory_order_release);
  shared_->wake.notify_one();
}

void ThreadedDevice::ShowModel(uint64_t cuts, bool contact) noexcept {
  cuts_ = cuts;
  contact_ = contact;
}

void ThreadedDevice::Stop() noexcept {
  if (stopped_) return;
  stopped_ = true;
  if (!started_) {
    shared_->device->Stop();
    return;
  }
  // Zero force as the thread's last command, then the thread ends.
  SetForce(Eigen::Vector3d::Zero());
  shared_->quit.store(true, std::memory_order_release);
  shared_->wake.fetch_add(1, std::memory_order_release);
  shared_->wake.notify_one();
  // After the loop: a bounded wait for the device thread.
  const int64_t until = MonotonicNs() + static_cast<int64_t>(std::llround(options_.stop_grace_s * 1e9));
  while (!shared_->done.load(std::memory_order_acquire) && MonotonicNs() < until) {
    std::this_thread::sleep_for(std::chrono::milliseconds(1));
  }
  if (shared_->done.load(std::memory_order_acquire)) {
    thread_.join();
    shared_->device->Stop();
    return;
  }
  // Still inside the device: it keeps the device; the station goes on.
  stats_.abandoned = true;
  thread_.detach();
  try {
    Log().error("device {}: its read or write_force has not returned within {:.3g} s of the stop; the device is left "
                "to its thread (not closed)",
                info_.name, options_.stop_grace_s);
  } catch (...) {  // the log is best effort here
  }
}

ThreadedDeviceStats ThreadedDevice::stats() const {
  ThreadedDeviceStats s = stats_;
  s.io_cycles = io_cycles();
  return s;
}

uint64_t ThreadedDevice::io_cycles() const { return shared_->cycles.load(std::memory_order_acquire); }

void ThreadedDevice::DeviceThread(const std::shared_ptr<Shared>& s, int64_t start_ns) {
  RunBelowTheLoop();
  Reading& first = s->readings.back();
  first.tick = -1;
  s->device->Read(start_ns, &first.state);
  s->readings.Publish();
  s->cycles.fetch_add(1, std::memory_order_release);
  for (;;) {
    // The wake-up count before looking for a command: a command posted
    // after the look changes it, so the wait below returns at once.
    const uint32_t seen = s->wake.load(std::memory_order_acquire);
    // Quit before the command: Stop posts its zero force before it sets
    // quit, so the last command is always served.
    const bool quit = s->quit.load(std::memory_order_acquire);
    if (s->commands.TakeFresh()) {
      const Command& c = s->commands.front();
      s->device->SetForce(c.force);
      s->device->ShowModel(c.cuts, c.contact);
      Reading& r = s->readings.back();
      r.tick = c.tick;
      s->device->Read(c.now_ns, &r.state);
      s->readings.Publish();
      s->cycles.fetch_add(1, std::memory_order_release);
    }
    if (quit) break;
    s->wake.wait(seen, std::memory_order_acquire);
  }
  s->done.store(true, std::memory_order_release);
}

}  // namespace cutsim::haptic_client

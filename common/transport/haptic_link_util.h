#pragma once
/// @file
/// Helpers shared by the two ends of the haptic link (haptic_link.cc,
/// haptic_client_link.cc); not part of the link's interface.

#include <poll.h>

#include <algorithm>
#include <cstdint>
#include <limits>
#include <memory>

#include "common/transport/fault_injection.h"
#include "common/transport/lcm_packet.h"
#include "common/transport/udpm_receiver.h"
#include "common/transport/wake_fd.h"

namespace cutsim::transport::link_detail {

inline std::unique_ptr<FaultInjector> MakeReceiveFaults(const FaultConfig& config) {
  ValidateFaultConfig(config);
  if (!config.active()) return nullptr;
  return std::make_unique<FaultInjector>(config);
}

/// Milliseconds from `now_ns` until `due_ns` (rounded up), capped at `cap_ms`.
inline int WaitMs(int64_t now_ns, int64_t due_ns, int cap_ms) {
  if (due_ns == std::numeric_limits<int64_t>::max()) return cap_ms;
  const int64_t until_due_ms = std::max<int64_t>(0, (due_ns - now_ns + 999'999) / 1'000'000);
  return static_cast<int>(std::min<int64_t>(cap_ms, until_due_ms));
}

/// Waits up to `timeout_ms` for the input descriptor (LCM's or the udpm
/// receiver's) or the wake-up eventfd. Returns whether input is ready
/// (EINTR counts as "maybe").
inline bool WaitInputOrWake(int input_fd, const WakeFd& wake, int timeout_ms) {
  pollfd fds[2] = {{.fd = input_fd, .events = POLLIN, .revents = 0},
                   {.fd = wake.fd(), .events = POLLIN, .revents = 0}};
  const int n = ::poll(fds, 2, timeout_ms);
  if (n < 0) return true;
  return (fds[0].revents & (POLLIN | POLLERR | POLLHUP)) != 0;
}

/// The counters as a report: `queued` (passed every check) minus those
/// taken is the superseded count; the receiver (null: LCM's subscription)
/// adds the kernel's drops.
PacketCounts SnapshotPackets(const PacketCounters& counters, uint64_t queued, const UdpmReceiver* receiver);

}  // namespace cutsim::transport::link_detail

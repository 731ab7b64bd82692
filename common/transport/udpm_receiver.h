#pragma once
/// @file
/// A packet-level receiver for one LCM channel on a `udpm://` URL, so that
/// the haptic link judges every datagram before anything queues it.
///
/// LCM's own udpm receive thread queues a message for a subscription
/// (capacity 1) before the subscriber sees it, and drops later arrivals
/// while one waits: a flood of junk on a channel then displaces the genuine
/// messages, and LCM counts neither the flood nor fragments anywhere we can
/// read. This receiver instead opens its own UDP socket on the LCM group and
/// port (SO_REUSEADDR, so it coexists with LCM's socket and other
/// processes'; bound to the group, IP_MULTICAST_ALL off, so only that
/// group's datagrams arrive), with a large receive buffer (SO_RCVBUFFORCE
/// where permitted, else SO_RCVBUF up to the system's limit), and reads it
/// in batches with `recvmmsg`. It parses LCM's header itself
/// (lcm_packet.h) and counts each datagram that is not a message on its
/// channel (garbage, fragment, another channel, larger than the buffer);
/// the rest go to the caller's handler, which judges and counts them. The
/// kernel's own drops on a full buffer are read from SO_RXQ_OVFL.
///
/// Publishing stays with LCM (`lcm_publish`); only udpm URLs have this
/// receiver (memq:// and the others keep LCM's subscription, counted per
/// delivered message, not per datagram).
///
/// Threading: one thread drains it. No allocation after construction.

#include <netinet/in.h>
#include <sys/socket.h>

#include <atomic>
#include <cstddef>
#include <cstdint>
#include <optional>
#include <span>
#include <string>
#include <string_view>
#include <vector>

#include "common/transport/lcm_packet.h"

namespace cutsim::transport {

/// The multicast group and port of a `udpm://GROUP:PORT?...` URL (LCM's
/// defaults for absent parts), or nullopt for any other provider.
struct UdpmAddress {
  in_addr group{};
  uint16_t port = 0;  ///< Host order.
};
[[nodiscard]] std::optional<UdpmAddress> ParseUdpmAddress(std::string_view url);

class UdpmReceiver {
 public:
  struct Options {
    int receive_buffer_bytes = 8 << 20;  ///< Requested SO_RCVBUF(FORCE).
    size_t batch = 64;                   ///< Datagrams per recvmmsg.
    size_t max_datagram = 2048;          ///< Buffer per datagram; longer ones are oversized.
    size_t max_payload = 1400;           ///< Larger payloads on our channel are oversized.
    int max_batches_per_drain = 64;      ///< Bounds one `Drain` (then the caller's loop runs again).
  };

  /// Opens and joins. Throws `std::runtime_error` naming the URL and the
  /// failing call (socket, bind, membership). `counters` must outlive it.
  UdpmReceiver(std::string_view url, std::string channel, PacketCounters& counters, Options options);
  UdpmReceiver(std::string_view url, std::string channel, PacketCounters& counters)
      : UdpmReceiver(url, std::move(channel), counters, Options{}) {}
  ~UdpmReceiver();
  UdpmReceiver(const UdpmReceiver&) = delete;
  UdpmReceiver& operator=(const UdpmReceiver&) = delete;

  /// Reads what is waiting without blocking and calls `on_message(payload,
  /// receive_ns)` (CLOCK_MONOTONIC of the batch) for each message on our
  /// channel with a payload within `max_payload`; the payload is valid
  /// during the call. Returns the datagrams read.
  template <class OnMessage>
  size_t Drain(OnMessage&& on_message) {
    size_t total = 0;
    for (int b = 0; b < options_.max_batches_per_drain; ++b) {
      const int n = ReceiveBatch();
      if (n <= 0) break;
      total += static_cast<size_t>(n);
      for (int i = 0; i < n; ++i) {
        const std::span<const uint8_t> payload = Classify(static_cast<size_t>(i));
        if (payload.data() != nullptr) on_message(payload, batch_ns_);
      }
      if (static_cast<size_t>(n) < options_.batch) break;
    }
    return total;
  }

  /// The socket, to `poll` for POLLIN.
  [[nodiscard]] int fd() const { return fd_; }
  [[nodiscard]] const std::string& channel() const { return channel_; }
  /// The receive buffer the kernel granted, bytes.
  [[nodiscard]] int receive_buffer_bytes() const { return rcvbuf_; }
  /// Datagrams the kernel dropped on this socket's full buffer (SO_RXQ_OVFL).
  /// Any thread.
  [[nodiscard]] uint64_t kernel_dropped() const { return kernel_dropped_.load(std::memory_order_relaxed); }
  /// Datagrams read so far (any thread).
  [[nodiscard]] uint64_t datagrams() const { return datagrams_.load(std::memory_order_relaxed); }

 private:
  /// One recvmmsg (non-blocking); returns the count, 0 when none waits.
  int ReceiveBatch() noexcept;
  /// Counts datagram `i` unless it is a message on our channel, whose
  /// payload it returns (a null span otherwise).
  std::span<const uint8_t> Classify(size_t i) noexcept;

  std::string channel_;
  PacketCounters& counters_;
  Options options_;
  int fd_ = -1;
  int rcvbuf_ = 0;
  std::vector<uint8_t> buffers_;   // batch × max_datagram
  std::vector<uint8_t> control_;   // batch × control space (SO_RXQ_OVFL)
  std::vector<iovec> iov_;
  std::vector<mmsghdr> msgs_;
  int64_t batch_ns_ = 0;
  std::atomic<uint64_t> kernel_dropped_{0};
  uint32_t last_ovfl_ = 0;
  std::atomic<uint64_t> datagrams_{0};
};

}  // namespace cutsim::transport

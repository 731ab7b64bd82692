#include "common/transport/udpm_receiver.h"

#include <arpa/inet.h>
#include <fcntl.h>
#include <unistd.h>

#include <cerrno>
#include <charconv>
#include <cstring>
#include <stdexcept>

#include <fmt/format.h>

#include "common/core/clock.h"

namespace cutsim::transport {
namespace {

constexpr std::string_view kScheme = "udpm://";
constexpr char kDefaultGroup[] = "239.255.76.67";
constexpr uint16_t kDefaultPort = 7667;

[[noreturn]] void Fail(std::string_view url, std::string_view what) {
  throw std::runtime_error(fmt::format("udpm receiver for {}: {}: {}", url, what, std::strerror(errno)));
}

}  // namespace

std::optional<UdpmAddress> ParseUdpmAddress(std::string_view url) {
  if (url.substr(0, kScheme.size()) != kScheme) return std::nullopt;
  std::string_view rest = url.substr(kScheme.size());
  rest = rest.substr(0, rest.find('?'));
  const size_t colon = rest.rfind(':');
  std::string group(rest.substr(0, colon));
  if (group.empty()) group = kDefaultGroup;
  UdpmAddress a;
  a.port = kDefaultPort;
  if (colon != std::string_view::npos) {
    const std::string_view port = rest.substr(colon + 1);
    unsigned v = 0;
    const auto [end, ec] = std::from_chars(port.data(), port.data() + port.size(), v);
    if (ec != std::errc() || end != port.data() + port.size() || v == 0 || v > 65535) return std::nullopt;
    a.port = static_cast<uint16_t>(v);
  }
  if (inet_aton(group.c_str(), &a.group) == 0) return std::nullopt;
  return a;
}

UdpmReceiver::UdpmReceiver(std::string_view url, std::string channel, PacketCounters& counters,
                           Options options)
    : channel_(std::move(channel)), counters_(counters), options_(options) {
  const auto address = ParseUdpmAddress(url);
  if (!address) throw std::runtime_error(fmt::format("udpm receiver: \"{}\" is not a udpm:// URL", url));
  fd_ = ::socket(AF_INET, SOCK_DGRAM | SOCK_NONBLOCK | SOCK_CLOEXEC, 0);
  if (fd_ < 0) Fail(url, "socket");
  try {
    const int one = 1;
    const int zero = 0;
    if (::setsockopt(fd_, SOL_SOCKET, SO_REUSEADDR, &one, sizeof(one)) != 0) Fail(url, "SO_REUSEADDR");
    // A big buffer rides out a burst while the thread is preempted. As root
    // SO_RCVBUFFORCE passes net.core.rmem_max; otherwise the kernel caps
    // SO_RCVBUF at rmem_max.
    const int want = options_.receive_buffer_bytes;
    if (::setsockopt(fd_, SOL_SOCKET, SO_RCVBUFFORCE, &want, sizeof(want)) != 0) {
      (void)::setsockopt(fd_, SOL_SOCKET, SO_RCVBUF, &want, sizeof(want));
    }
    socklen_t len = sizeof(rcvbuf_);
    (void)::getsockopt(fd_, SOL_SOCKET, SO_RCVBUF, &rcvbuf_, &len);
    (void)::setsockopt(fd_, SOL_SOCKET, SO_RXQ_OVFL, &one, sizeof(one));
    sockaddr_in addr{};
    addr.sin_family = AF_INET;
    addr.sin_addr = address->group;  // only this group's datagrams
    addr.sin_port = htons(address->port);
    if (::bind(fd_, reinterpret_cast<const sockaddr*>(&addr), sizeof(addr)) != 0) Fail(url, "bind");
    // Without this, a socket bound to the port would also get other groups
    // joined by any socket of the host.
    (void)::setsockopt(fd_, IPPROTO_IP, IP_MULTICAST_ALL, &zero, sizeof(zero));
    ip_mreq mreq{};
    mreq.imr_multiaddr = address->group;
    mreq.imr_interface.s_addr = htonl(INADDR_ANY);
    if (::setsockopt(fd_, IPPROTO_IP, IP_ADD_MEMBERSHIP, &mreq, sizeof(mreq)) != 0) {
      Fail(url, "IP_ADD_MEMBERSHIP");
    }
  } catch (...) {
    ::close(fd_);
    throw;
  }
  const size_t batch = options_.batch;
  const size_t control = CMSG_SPACE(sizeof(uint32_t));
  buffers_.resize(batch * options_.max_datagram);
  control_.resize(batch * control);
  iov_.resize(batch);
  msgs_.resize(batch);
  for (size_t i = 0; i < batch; ++i) {
    iov_[i] = {.iov_base = buffers_.data() + i * options_.max_datagram, .iov_len = options_.max_datagram};
  }
}

UdpmReceiver::~UdpmReceiver() {
  if (fd_ >= 0) ::close(fd_);
}

int UdpmReceiver::ReceiveBatch() noexcept {
  const size_t control = CMSG_SPACE(sizeof(uint32_t));
  for (size_t i = 0; i < msgs_.size(); ++i) {
    msghdr& h = msgs_[i].msg_hdr;
    h = msghdr{};
    h.msg_iov = &iov_[i];
    h.msg_iovlen = 1;
    h.msg_control = control_.data() + i * control;
    h.msg_controllen = control;
    msgs_[i].msg_len = 0;
  }
  const int n = ::recvmmsg(fd_, msgs_.data(), static_cast<unsigned>(msgs_.size()), MSG_DONTWAIT, nullptr);
  if (n <= 0) return 0;
  batch_ns_ = MonotonicNs();
  datagrams_.fetch_add(static_cast<uint64_t>(n), std::memory_order_relaxed);
  // The drop count is cumulative; the newest datagram's carries the latest.
  for (int i = n - 1; i >= 0; --i) {
    msghdr& h = msgs_[static_cast<size_t>(i)].msg_hdr;
    bool found = false;
    for (cmsghdr* c = CMSG_FIRSTHDR(&h); c != nullptr; c = CMSG_NXTHDR(&h, c)) {
      if (c->cmsg_level == SOL_SOCKET && c->cmsg_type == SO_RXQ_OVFL) {
        uint32_t total = 0;
        std::memcpy(&total, CMSG_DATA(c), sizeof(total));
        kernel_dropped_.fetch_add(static_cast<uint32_t>(total - last_ovfl_), std::memory_order_relaxed);
        last_ovfl_ = total;
        found = true;
        break;
      }
    }
    if (found) break;
  }
  return n;
}

std::span<const uint8_t> UdpmReceiver::Classify(size_t i) noexcept {
  const mmsghdr& m = msgs_[i];
  if ((m.msg_hdr.msg_flags & MSG_TRUNC) != 0) {
    counters_.Add(PacketReason::kOversized);
    return {};
  }
  const std::span<const uint8_t> datagram(buffers_.data() + i * options_.max_datagram, m.msg_len);
  const LcmPacket p = ParseLcmPacket(datagram);
  switch (p.kind) {
    case LcmPacketKind::kNotLcm:
      counters_.Add(PacketReason::kNotLcm);
      return {};
    case LcmPacketKind::kFragment:
      counters_.Add(PacketReason::kFragment);
      return {};
    case LcmPacketKind::kMessage:
      break;
  }
  if (p.channel != channel_) {
    counters_.Add(PacketReason::kOtherChannel);
    return {};
  }
  if (p.payload.size() > options_.max_payload) {
    counters_.Add(PacketReason::kOversized);
    return {};
  }
  // An empty payload is still a message (an empty protobuf); keep a non-null view.
  return p.payload.data() != nullptr ? p.payload : datagram.subspan(datagram.size());
}

}  // namespace cutsim::transport

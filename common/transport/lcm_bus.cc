#include "common/transport/lcm_bus.h"

#include <algorithm>
#include <charconv>
#include <arpa/inet.h>
#include <cstring>
#include <fstream>
#include <sstream>

#include <fmt/format.h>
#include <lcm/lcm.h>

#include "common/core/clock.h"
#include "common/core/error.h"
#include "common/core/log.h"

namespace cutsim::transport {
namespace {

constexpr int64_t kWarnPeriodNs = 1'000'000'000;  // at most one warning per second per source
constexpr size_t kMaxLcmChannelLength = 63;       // LCM_MAX_CHANNEL_NAME_LENGTH
constexpr int kMaxDrainPerHandle = 4096;          // bounds one HandleTimeout's dispatch loop

lcm_t* AsLcm(void* p) { return static_cast<lcm_t*>(p); }

/// Exact channel names only: LCM compiles a subscribed channel as a regex.
bool IsValidChannelName(std::string_view channel) {
  if (channel.empty() || channel.size() > kMaxLcmChannelLength) return false;
  return std::all_of(channel.begin(), channel.end(), [](char c) {
    return (c >= 'a' && c <= 'z') || (c >= 'A' && c <= 'Z') || (c >= '0' && c <= '9') ||
           c == '_' || c == '-';
  });
}

bool RateLimit(int64_t& last_ns) {
  const int64_t now = MonotonicNs();
  if (last_ns != 0 && now - last_ns < kWarnPeriodNs) return false;
  last_ns = now;
  return true;
}

/// For udpm URLs: the multicast group and the TTL (LCM's defaults if absent).
struct UdpmTarget {
  std::string group = "239.255.76.67";
  int ttl = 0;
};

std::optional<UdpmTarget> ParseUdpm(std::string_view url) {
  constexpr std::string_view kScheme = "udpm://";
  if (url.substr(0, kScheme.size()) != kScheme) return std::nullopt;
  UdpmTarget target;
  std::string_view rest = url.substr(kScheme.size());
  const size_t q = rest.find('?');
  const std::string_view address = rest.substr(0, q);
  const std::string_view group = address.substr(0, address.find(':'));
  if (!group.empty()) target.group = std::string(group);
  if (q != std::string_view::npos) {
    const std::string_view options = rest.substr(q + 1);
    const size_t t = options.find("ttl=");
    if (t != std::string_view::npos) target.ttl = std::atoi(std::string(options.substr(t + 4)).c_str());
  }
  return target;
}

}  // namespace

void ValidateLcmUrl(std::string_view url, std::string_view field) {
  auto fail = [&](std::string_view why) {
    ThrowInputError(SourceRef{.field = std::string(field)},
                    fmt::format("invalid LCM URL \"{}\": {}; e.g. {} or memq://", url, why, kDefaultLcmUrl));
  };
  const size_t scheme_end = url.find("://");
  if (url.empty() || scheme_end == std::string_view::npos || scheme_end == 0) {
    fail("expected provider://address?options");
  }
  const std::string_view provider = url.substr(0, scheme_end);
  std::string_view rest = url.substr(scheme_end + 3);
  const size_t q = rest.find('?');
  const std::string_view address = rest.substr(0, q);
  const std::string_view options = q == std::string_view::npos ? std::string_view() : rest.substr(q + 1);
  auto parse_int = [&](std::string_view text, int64_t lo, int64_t hi, std::string_view what) {
    int64_t v = 0;
    const auto [end, ec] = std::from_chars(text.data(), text.data() + text.size(), v);
    if (text.empty() || ec != std::errc() || end != text.data() + text.size() || v < lo || v > hi) {
      fail(fmt::format("{} \"{}\" is not an integer in [{}, {}]", what, text, lo, hi));
    }
    return v;
  };
  auto check_port = [&](std::string_view host_port, bool need_multicast) {
    const size_t colon = host_port.rfind(':');
    const std::string_view host = host_port.substr(0, colon);
    if (colon != std::string_view::npos) parse_int(host_port.substr(colon + 1), 1, 65535, "port");
    if (need_multicast && !host.empty()) {
      in_addr addr{};
      if (inet_aton(std::string(host).c_str(), &addr) == 0 || (ntohl(addr.s_addr) >> 28) != 0xE) {
        fail(fmt::format("\"{}\" is not an IPv4 multicast group (224.0.0.0/4)", host));
      }
    }
  };
  if (provider == "udpm") {
    check_port(address, /*need_multicast=*/true);
    size_t start = 0;
    while (start < options.size()) {
      const size_t amp = options.find('&', start);
      const std::string_view opt = options.substr(start, amp == std::string_view::npos ? amp : amp - start);
      const size_t eq = opt.find('=');
      const std::string_view key = opt.substr(0, eq);
      const std::string_view value = eq == std::string_view::npos ? std::string_view() : opt.substr(eq + 1);
      if (key == "ttl") {
        parse_int(value, 0, 255, "ttl");
      } else if (key == "recv_buf_size") {
        parse_int(value, 1, int64_t{1} << 30, "recv_buf_size");
      } else {
        fail(fmt::format("unknown udpm option \"{}\" (ttl, recv_buf_size)", key));
      }
      if (amp == std::string_view::npos) break;
      start = amp + 1;
    }
  } else if (provider == "tcpq") {
    check_port(address, /*need_multicast=*/false);
  } else if (provider != "memq" && provider != "file" && provider != "mpudpm") {
    fail(fmt::format("unknown provider \"{}\" (udpm, mpudpm, memq, tcpq, file)", provider));
  }
}

namespace {

/// Interface of the longest-prefix IPv4 route for `group` in /proc/net/route
/// (empty if none or unreadable).
std::string RouteInterface(const std::string& group) {
  in_addr addr{};
  if (inet_aton(group.c_str(), &addr) == 0) return {};
  std::ifstream routes("/proc/net/route");
  std::string line;
  std::getline(routes, line);  // header
  std::string best;
  int best_bits = -1;
  while (std::getline(routes, line)) {
    std::istringstream fields(line);
    std::string iface, dest_hex, gateway_hex, flags, refcnt, use, metric, mask_hex;
    if (!(fields >> iface >> dest_hex >> gateway_hex >> flags >> refcnt >> use >> metric >> mask_hex)) {
      continue;
    }
    // The file prints addresses as host-order hex of the network-order value.
    const auto dest = static_cast<uint32_t>(std::stoul(dest_hex, nullptr, 16));
    const auto mask = static_cast<uint32_t>(std::stoul(mask_hex, nullptr, 16));
    if ((addr.s_addr & mask) != dest) continue;
    const int bits = __builtin_popcount(mask);
    if (bits > best_bits) {
      best_bits = bits;
      best = iface;
    }
  }
  return best;
}

void WarnIfUdpmLeavesLoopback(std::string_view url) {
  const std::optional<UdpmTarget> target = ParseUdpm(url);
  if (!target) return;
  if (target->ttl > 0) {
    Log().warn("LCM URL {} has ttl={}: datagrams can reach other machines", url, target->ttl);
  }
  try {
    const std::string iface = RouteInterface(target->group);
    if (!iface.empty() && iface != "lo") {
      Log().warn(
          "LCM multicast group {} is routed via {}, not lo: with ttl=0 no datagram leaves this "
          "host, but the kernel sends IGMP membership reports on {}. To keep everything on "
          "loopback: ip link set lo multicast on && ip route add {}/32 dev lo",
          target->group, iface, iface, target->group);
    }
  } catch (const std::exception&) {
    // Unparsable routing table: this is only advice, say nothing.
  }
}

}  // namespace

// ---- detail::LcmSubscriptionState ------------------------------------------

void detail::LcmSubscriptionState::Receive(const void* data, size_t size) noexcept {
  ++stats_.received;
  if (has_pending_ || oversized_pending_) ++stats_.superseded;
  if (size > max_bytes_) {
    // Not copied: remember only that the newest message is unusable.
    has_pending_ = false;
    oversized_pending_ = true;
    oversized_size_ = size;
    return;
  }
  oversized_pending_ = false;
  try {
    if (pending_.size() < size) pending_.resize(size);
  } catch (...) {
    has_pending_ = false;
    ++stats_.decode_errors;
    return;
  }
  if (size > 0) std::memcpy(pending_.data(), data, size);
  pending_size_ = size;
  has_pending_ = true;
}

bool detail::LcmSubscriptionState::DeliverPending() {
  if (oversized_pending_) {
    oversized_pending_ = false;
    ++stats_.decode_errors;
    last_error_ = DecodeError{.status = DecodeStatus::kTooLarge,
                              .source = channel_,
                              .type_name = type_name_,
                              .size = oversized_size_,
                              .limit = max_bytes_};
    if (RateLimit(last_warn_ns_)) Log().warn("dropped message: {}", last_error_.Message());
    return false;
  }
  if (!has_pending_) return false;
  has_pending_ = false;
  DecodeError err;
  if (!DecodeAndCall(std::span<const uint8_t>(pending_.data(), pending_size_), &err)) {
    ++stats_.decode_errors;
    last_error_ = err;
    if (RateLimit(last_warn_ns_)) Log().warn("dropped message: {}", err.Message());
    return false;
  }
  ++stats_.delivered;
  return true;
}

// ---- LcmSubscription ---------------------------------------------------------

LcmSubscription::~LcmSubscription() { Release(); }

LcmSubscription& LcmSubscription::operator=(LcmSubscription&& other) noexcept {
  if (this != &other) {
    Release();
    bus_ = std::exchange(other.bus_, nullptr);
    state_ = std::move(other.state_);
  }
  return *this;
}

void LcmSubscription::Release() noexcept {
  if (bus_ != nullptr && state_ != nullptr) bus_->Unregister(state_.get());
  bus_ = nullptr;
  state_.reset();
}

const std::string& LcmSubscription::channel() const {
  CUTSIM_CHECK(state_ != nullptr, "inactive LcmSubscription");
  return state_->channel();
}

const LcmSubscriptionStats& LcmSubscription::stats() const {
  CUTSIM_CHECK(state_ != nullptr, "inactive LcmSubscription");
  return state_->stats();
}

const DecodeError& LcmSubscription::last_error() const {
  CUTSIM_CHECK(state_ != nullptr, "inactive LcmSubscription");
  return state_->last_error();
}

// ---- LcmBus --------------------------------------------------------------------

LcmBus::LcmBus(std::string_view url, size_t max_payload_bytes)
    : url_(url), max_payload_bytes_(max_payload_bytes) {
  ValidateLcmUrl(url_);
  lcm_ = lcm_create(url_.c_str());
  if (lcm_ == nullptr) {
    ThrowInputError(SourceRef{.field = "--lcm-url"},
                    fmt::format("LCM cannot open \"{}\" (unknown provider, bad address or port, "
                                "or no multicast route); e.g. {} or memq://",
                                url_, kDefaultLcmUrl));
  }
  WarnIfUdpmLeavesLoopback(url_);
}

LcmBus::~LcmBus() {
  // Subscriptions point into this bus; destroying it first is a bug.
  CUTSIM_CHECK(subscriptions_.empty(), "LcmBus destroyed before its subscriptions");
  lcm_destroy(AsLcm(lcm_));
}

PublishStatus LcmBus::Publish(std::string_view channel,
                              const google::protobuf::MessageLite& msg) noexcept {
  try {
    size_t size = 0;
    const auto bytes = encoder_.Encode(msg, max_payload_bytes_, &size);
    if (!bytes) {
      if (size > max_payload_bytes_) {
        ++stats_.publish_too_large;
        if (RateLimit(last_publish_warn_ns_)) {
          Log().warn("not publishing {} on {}: {} bytes exceeds the {}-byte datagram limit "
                     "(LCM drops fragmented messages under loss)",
                     msg.GetTypeName(), channel, size, max_payload_bytes_);
        }
        return PublishStatus::kTooLarge;
      }
      ++stats_.publish_failed;
      return PublishStatus::kFailed;
    }
    return PublishBytes(channel, *bytes);
  } catch (...) {
    ++stats_.publish_failed;
    return PublishStatus::kFailed;
  }
}

PublishStatus LcmBus::PublishBytes(std::string_view channel,
                                   std::span<const uint8_t> bytes) noexcept {
  // lcm_publish needs a NUL-terminated channel; channels are short.
  char name[kMaxLcmChannelLength + 1];
  if (channel.empty() || channel.size() > kMaxLcmChannelLength) {
    ++stats_.publish_failed;
    return PublishStatus::kFailed;
  }
  std::memcpy(name, channel.data(), channel.size());
  name[channel.size()] = '\0';
  if (bytes.size() > max_payload_bytes_) {
    ++stats_.publish_too_large;
    return PublishStatus::kTooLarge;
  }
  if (lcm_publish(AsLcm(lcm_), name, bytes.data(), static_cast<unsigned>(bytes.size())) != 0) {
    ++stats_.publish_failed;
    return PublishStatus::kFailed;
  }
  ++stats_.published;
  return PublishStatus::kOk;
}

namespace {
extern "C" void LcmRawHandler(const lcm_recv_buf_t* rbuf, const char* /*channel*/,
                              void* user) {
  // A C callback: Receive is noexcept and only copies bytes.
  static_cast<detail::LcmSubscriptionState*>(user)->Receive(rbuf->data, rbuf->data_size);
}
}  // namespace

LcmSubscription LcmBus::Register(std::unique_ptr<detail::LcmSubscriptionState> state) {
  if (!IsValidChannelName(state->channel())) {
    ThrowInputError(SourceRef{.field = "channel"},
                    fmt::format("invalid LCM channel \"{}\": use 1 to {} characters of "
                                "A-Z, a-z, 0-9, '_' and '-'",
                                state->channel(), kMaxLcmChannelLength));
  }
  lcm_subscription_t* sub =
      lcm_subscribe(AsLcm(lcm_), state->channel().c_str(), &LcmRawHandler, state.get());
  CUTSIM_CHECK(sub != nullptr, "lcm_subscribe failed on a validated channel name");
  // Stale messages are dropped, not queued (see the file comment).
  CUTSIM_CHECK(lcm_subscription_set_queue_capacity(sub, 1) == 0,
               "lcm_subscription_set_queue_capacity failed");
  state->lcm_subscription_ = sub;
  subscriptions_.push_back(state.get());
  return LcmSubscription(this, std::move(state));
}

void LcmBus::Unregister(detail::LcmSubscriptionState* state) noexcept {
  lcm_unsubscribe(AsLcm(lcm_), static_cast<lcm_subscription_t*>(state->lcm_subscription_));
  closed_decode_errors_ += state->stats().decode_errors;
  closed_received_ += state->stats().received;
  std::erase(subscriptions_, state);
}

int LcmBus::HandleTimeout(int timeout_ms) {
  CUTSIM_CHECK(timeout_ms >= 0, "HandleTimeout needs a non-negative timeout");
  int status = lcm_handle_timeout(AsLcm(lcm_), timeout_ms);
  // Then everything already waiting, without blocking again.
  for (int i = 0; status > 0 && i < kMaxDrainPerHandle; ++i) {
    status = lcm_handle_timeout(AsLcm(lcm_), 0);
  }
  if (status < 0) ++stats_.handle_errors;
  int delivered = 0;
  // By index: a callback may subscribe (push_back can reallocate).
  for (size_t i = 0; i < subscriptions_.size(); ++i) {
    if (subscriptions_[i]->DeliverPending()) ++delivered;
  }
  return delivered;
}

int LcmBus::fileno() const { return lcm_get_fileno(AsLcm(lcm_)); }

uint64_t LcmBus::decode_errors() const {
  uint64_t n = closed_decode_errors_;
  for (const auto* s : subscriptions_) n += s->stats().decode_errors;
  return n;
}

uint64_t LcmBus::received() const {
  uint64_t n = closed_received_;
  for (const auto* s : subscriptions_) n += s->stats().received;
  return n;
}

}  // namespace cutsim::transport

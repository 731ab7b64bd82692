#include "common/transport/server_presence.h"

#include <unistd.h>

#include <algorithm>
#include <chrono>
#include <ctime>

#include <fmt/format.h>

#include "common/core/clock.h"
#include "common/core/log.h"
#include "common/core/stop.h"
#include "common/transport/channels.h"
#include "common/transport/codec.h"
#include "common/transport/lcm_bus.h"
#include "cutsim/v1/wire.pb.h"

namespace cutsim::transport {
namespace {

constexpr char kDomain[] = "cutsim.v1.ServerPresence/hmac-sha256/1";
constexpr int64_t kConflictLogPeriodNs = 5'000'000'000;

std::string HostName() {
  char name[256] = {};
  if (::gethostname(name, sizeof(name) - 1) != 0) return "?";
  return name;
}

}  // namespace

std::string PeerServer::Describe() const {
  const auto seconds = static_cast<time_t>(epoch / 1'000'000'000);
  std::tm utc{};
  gmtime_r(&seconds, &utc);
  char when[32] = {};
  std::strftime(when, sizeof(when), "%Y-%m-%d %H:%M:%S", &utc);
  return fmt::format("cutsim-server pid {} on host {}, started {} UTC", pid, host, when);
}

ServerPresence::ServerPresence(ServerPresenceOptions options)
    : options_(std::move(options)),
      epoch_(static_cast<uint64_t>(RealtimeNowNs())),
      host_(HostName()),
      pid_(static_cast<uint32_t>(::getpid())) {
  if (options_.key) {
    auth_ = std::make_unique<PayloadAuthenticator>(*options_.key, kDomain, options_.session);
  }
  bus_ = std::make_unique<LcmBus>(options_.lcm_url);
  subscription_ = std::make_unique<LcmSubscription>(bus_->SubscribeRaw(
      LcmChannelName(options_.session, LcmChannel::kServer), MaxPayloadBytes<v1::ServerPresence>(),
      [this](std::span<const uint8_t> bytes) { OnMessage(bytes); }));
}

ServerPresence::~ServerPresence() {
  stop_.store(true, std::memory_order_release);
  if (thread_.joinable()) thread_.join();
  subscription_.reset();  // before its bus
}

void ServerPresence::Announce(bool probe) {
  v1::ServerPresence msg;
  msg.set_session(options_.session);
  msg.set_epoch(epoch_);
  msg.set_seq(++seq_);
  msg.set_wall_ns(RealtimeNowNs());
  msg.set_host(host_);
  msg.set_pid(pid_);
  msg.set_probe(probe);
  Encoder encoder;
  const auto bytes = encoder.Encode(msg, nullptr, auth_.get());
  if (!bytes) return;
  if (bus_->PublishBytes(LcmChannelName(options_.session, LcmChannel::kServer), *bytes) ==
      PublishStatus::kOk) {
    std::lock_guard lock(mutex_);
    ++stats_.announced;
  }
}

void ServerPresence::OnMessage(std::span<const uint8_t> bytes) {
  std::span<const uint8_t> body = bytes;
  v1::ServerPresence msg;
  const bool authentic = auth_ == nullptr || auth_->Check(bytes, &body) == AuthVerdict::kOk;
  const int64_t now = RealtimeNowNs();
  const bool fresh = [&] {
    if (!authentic || !msg.ParseFromArray(body.data(), static_cast<int>(body.size()))) return false;
    if (msg.session() != options_.session || msg.epoch() == 0 || msg.wall_ns() < 0 ||
        msg.epoch() > static_cast<uint64_t>(msg.wall_ns())) {
      return false;
    }
    const int64_t skew = msg.wall_ns() > now ? msg.wall_ns() - now : now - msg.wall_ns();
    return auth_ == nullptr || skew <= options_.window_ns;
  }();
  if (!fresh) {
    bool first_one = false;
    {
      std::lock_guard lock(mutex_);
      first_one = stats_.unauthenticated++ == 0;
    }
    // Once: a server with another key on the session, a forger or a replay
    // is worth a line, and a test can see the message arrived and was ignored.
    if (first_one) {
      Log().warn("session '{}': ignored a server message that failed its check (another session key, "
                 "unsigned, stale or malformed); later ones are counted, not logged",
                 options_.session);
    }
    return;
  }
  if (msg.epoch() == epoch_ && msg.pid() == pid_ && msg.host() == host_) return;  // our own, looped back
  const PeerServer peer{.epoch = msg.epoch(), .host = msg.host(), .pid = msg.pid()};
  {
    std::lock_guard lock(mutex_);
    ++stats_.peers;
  }
  // Who gives way: while claiming, any server that runs, or an older prober;
  // while running, only to an older running server (a simultaneous start).
  const bool peer_is_older = msg.epoch() < epoch_ || (msg.epoch() == epoch_ && msg.pid() < pid_);
  const bool give_way = running_phase_ ? (!msg.probe() && peer_is_older) : (!msg.probe() || peer_is_older);
  if (give_way) {
    std::lock_guard lock(mutex_);
    if (!refused_by_) refused_by_ = peer;
    refused_.store(true, std::memory_order_release);
    return;
  }
  if (!running_phase_) return;  // two probers: the older one answers once it runs
  if (msg.probe()) {
    Announce(false);  // tell the newcomer at once
    std::lock_guard lock(mutex_);
    ++stats_.probes_answered;
  }
  const int64_t mono = MonotonicNs();
  if (mono - last_conflict_log_ns_ >= kConflictLogPeriodNs) {
    last_conflict_log_ns_ = mono;
    Log().warn("session '{}': a second server ({}) tried to serve this session; it is told to "
               "refuse, this server goes on",
               options_.session, peer.Describe());
  }
}

std::optional<PeerServer> ServerPresence::Claim() {
  Announce(true);
  const int64_t deadline = MonotonicNs() + int64_t{options_.probe_ms} * 1'000'000;
  for (int64_t now = MonotonicNs(); now < deadline && !refused(); now = MonotonicNs()) {
    bus_->HandleTimeout(static_cast<int>(std::max<int64_t>(1, (deadline - now) / 1'000'000)));
  }
  return refused_by();
}

void ServerPresence::Start() {
  if (thread_.joinable()) return;
  running_phase_ = true;
  thread_ = std::thread([this] { Run(); });
}

void ServerPresence::Run() {
  int64_t next = MonotonicNs();
  bool said = false;
  while (!stop_.load(std::memory_order_acquire)) {
    if (MonotonicNs() >= next) {
      Announce(false);
      next += int64_t{options_.period_ms} * 1'000'000;
    }
    bus_->HandleTimeout(50);
    if (refused() && !said) {
      said = true;
      if (const auto peer = refused_by()) {
        Log().error("session '{}' is also served by {}, which started first: this server stops. "
                    "Stop one of them, or give this one another --session.",
                    options_.session, peer->Describe());
      }
      RequestStop();
    }
  }
}

std::optional<PeerServer> ServerPresence::refused_by() const {
  std::lock_guard lock(mutex_);
  return refused_by_;
}

ServerPresenceStats ServerPresence::stats() const {
  std::lock_guard lock(mutex_);
  return stats_;
}

}  // namespace cutsim::transport

#include "common/transport/session_directory.h"

#include <algorithm>
#include <utility>

#include "common/core/clock.h"
#include "common/transport/codec.h"

namespace cutsim::transport {

SessionDirectory::SessionDirectory(SessionDirectoryOptions options) : options_(std::move(options)) {}

SessionDirectory::SessionDirectory(DdsParticipant& participant, SessionDirectoryOptions options)
    : SessionDirectory(std::move(options)) {
  topic_ = std::make_unique<DdsTopic>(participant, EnvelopeKind::kStatus);
  reader_ = std::make_unique<DdsReader>(*topic_, AnySession{});
}

SessionDirectory::~SessionDirectory() = default;

size_t SessionDirectory::Poll(std::chrono::nanoseconds timeout) {
  if (!reader_) return 0;
  size_t taken = 0;
  reader_->Take(timeout, [&](const EnvelopeView& e) {
    if (Process(e.session, e.payload, MonotonicNs())) ++taken;
  });
  return taken;
}

bool SessionDirectory::Process(std::string_view session, std::span<const uint8_t> payload, int64_t now_ns) {
  auto it = sessions_.find(session);
  if (it == sessions_.end() && sessions_.size() >= options_.max_sessions) {
    // Make room only by forgetting what is due; a full list of live
    // sessions refuses newcomers rather than dropping one it shows.
    (void)Entries(now_ns);
    if (sessions_.size() >= options_.max_sessions) {
      ++stats_.refused_full;
      return false;
    }
  }
  std::unique_ptr<PayloadAuthenticator> fresh_verifier;
  PayloadAuthenticator* verifier = nullptr;
  if (options_.key) {
    if (it != sessions_.end()) {
      verifier = it->second.verifier.get();
    } else {
      fresh_verifier = std::make_unique<PayloadAuthenticator>(
          *options_.key, std::string(ObserverStreamDomain(EnvelopeKind::kStatus)), std::string(session));
      verifier = fresh_verifier.get();
    }
  }
  std::span<const uint8_t> body = payload;
  if (verifier != nullptr) {
    switch (verifier->Check(payload, &body)) {
      case AuthVerdict::kOk:
        break;
      case AuthVerdict::kUnsigned:
        ++stats_.unsigned_samples;
        return false;
      default:
        ++stats_.forged;
        return false;
    }
  }
  if (!DecodeInto(body, msg_, TopicSpecFor(EnvelopeKind::kStatus).name) || msg_.session() != session) {
    ++stats_.malformed;
    return false;
  }
  if (it == sessions_.end()) {
    Held held;
    held.entry.session = std::string(session);
    held.entry.first_heard_ns = now_ns;
    held.verifier = std::move(fresh_verifier);
    it = sessions_.emplace(std::string(session), std::move(held)).first;
  }
  SessionEntry& e = it->second.entry;
  const v1::SessionStatus& prev = e.status;
  const bool same_server = e.statuses > 0 && prev.epoch() == msg_.epoch();
  if (same_server && msg_.frame() <= prev.frame()) {
    ++stats_.stale;
    return false;
  }
  if (same_server) {
    e.trainee_connected = msg_.tool_messages() > prev.tool_messages();
    const double dt = msg_.wall_time() - prev.wall_time();
    const double overruns = static_cast<double>(msg_.frame_overruns() - std::min(msg_.frame_overruns(), prev.frame_overruns()));
    e.overruns_per_s = dt > 0 ? overruns / dt : 0.0;
  } else {
    // A first status, or a restarted server: nothing to compare with yet.
    e.trainee_connected = false;
    e.overruns_per_s = 0;
  }
  e.status.Swap(&msg_);
  e.last_heard_ns = now_ns;
  ++e.statuses;
  ++stats_.statuses;
  return true;
}

std::vector<SessionEntry> SessionDirectory::Entries(int64_t now_ns) {
  const int64_t live_ns = std::chrono::nanoseconds(options_.live_window).count();
  const int64_t forget_ns = std::chrono::nanoseconds(options_.forget_after).count();
  std::vector<SessionEntry> out;
  out.reserve(sessions_.size());
  for (auto it = sessions_.begin(); it != sessions_.end();) {
    const int64_t silent = now_ns - it->second.entry.last_heard_ns;
    if (silent > live_ns + forget_ns) {
      it = sessions_.erase(it);
      ++stats_.forgotten;
      continue;
    }
    SessionEntry e = it->second.entry;
    e.live = silent <= live_ns;
    if (!e.live) e.trainee_connected = false;
    out.push_back(std::move(e));
    ++it;
  }
  return out;
}

}  // namespace cutsim::transport

#include "common/transport/debrief_control.h"

#include <utility>

#include "common/core/clock.h"
#include "common/transport/channels.h"

namespace cutsim::transport {
namespace {

/// Longest command line carried, bytes (debrief_command.h's limit).
constexpr size_t kMaxControlCommandBytes = 64;

std::unique_ptr<PayloadAuthenticator> Authenticator(const std::optional<SessionKey>& key, const std::string& session) {
  if (!key) return nullptr;
  return std::make_unique<PayloadAuthenticator>(*key, std::string(ObserverStreamDomain(EnvelopeKind::kControl)),
                                                session);
}

}  // namespace

DebriefControlWriter::DebriefControlWriter(DdsParticipant& participant, std::string session,
                                           std::optional<SessionKey> key)
    : session_(std::move(session)),
      topic_(participant, EnvelopeKind::kControl),
      writer_(topic_),
      signer_(Authenticator(key, session_)),
      epoch_(static_cast<uint64_t>(RealtimeNowNs())) {
  ValidateSessionName(session_, "--session");
}

bool DebriefControlWriter::Send(std::string_view command) {
  if (command.size() > kMaxControlCommandBytes) return false;
  msg_.Clear();
  msg_.set_command(std::string(command));
  msg_.set_seq(++seq_);
  if (signer_) {
    msg_.set_epoch(epoch_);
    msg_.set_wall_ns(RealtimeNowNs());
  }
  const auto bytes = encoder_.Encode(msg_, nullptr, signer_.get());
  if (!bytes) return false;
  return writer_.Publish(EnvelopeKind::kControl, seq_, session_, *bytes) == DdsPublishStatus::kOk;
}

DebriefControlReader::DebriefControlReader(DdsParticipant& participant, std::string session,
                                           std::optional<SessionKey> key)
    : session_(std::move(session)),
      topic_(participant, EnvelopeKind::kControl),
      reader_(topic_, session_),
      verifier_(Authenticator(key, session_)) {}

size_t DebriefControlReader::Poll(std::chrono::nanoseconds timeout,
                                  const std::function<void(const std::string&)>& fn) {
  size_t delivered = 0;
  reader_.Take(timeout, [&](const EnvelopeView& e) {
    std::span<const uint8_t> body = e.payload;
    if (verifier_) {
      switch (verifier_->Check(e.payload, &body)) {
        case AuthVerdict::kOk:
          break;
        case AuthVerdict::kUnsigned:
          ++stats_.unsigned_samples;
          return;
        default:
          ++stats_.forged;
          return;
      }
    }
    if (!DecodeInto(body, msg_, e.topic) || msg_.command().size() > kMaxControlCommandBytes) {
      ++stats_.malformed;
      return;
    }
    if (verifier_ && !Accepted(gate_.Offer(msg_.epoch(), msg_.seq(), msg_.wall_ns(), RealtimeNowNs(),
                                           MonotonicNs()))) {
      ++stats_.stale;
      return;
    }
    ++stats_.accepted;
    ++delivered;
    fn(msg_.command());
  });
  return delivered;
}

}  // namespace cutsim::transport

#pragma once
/// @file
/// The event journal's records signed with the session key
/// (sim::JournalSigner): the streams' HMAC-SHA256 trailer (stream_auth.h),
/// under a domain of its own, so no stream message's tag passes for a
/// journal record's. Records are not bound to one session name: a session
/// may resume under another; the header's lineage, which the tag covers,
/// ties a journal to its checkpoint.

#include <string>
#include <string_view>

#include "common/sim/journal_signer.h"
#include "common/transport/stream_auth.h"

namespace cutsim::transport {

/// The domain of journal tags.
inline constexpr const char* kJournalAuthDomain = "cutsim.v1.Journal/hmac-sha256/1";

class HmacJournalSigner final : public sim::JournalSigner {
 public:
  /// Throws like `HmacSha256`.
  explicit HmacJournalSigner(const SessionKey& key);

  [[nodiscard]] std::string Sign(std::string payload) override;
  [[nodiscard]] Verdict Check(std::string_view payload, size_t* body_size) override;

 private:
  PayloadAuthenticator auth_;
};

}  // namespace cutsim::transport

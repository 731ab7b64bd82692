#include "common/transport/journal_auth.h"

#include <array>
#include <cstdint>
#include <span>
#include <stdexcept>

namespace cutsim::transport {
namespace {

std::span<const uint8_t> Bytes(std::string_view s) {
  return {reinterpret_cast<const uint8_t*>(s.data()), s.size()};
}

}  // namespace

HmacJournalSigner::HmacJournalSigner(const SessionKey& key) : auth_(key, kJournalAuthDomain, "") {}

std::string HmacJournalSigner::Sign(std::string payload) {
  std::array<uint8_t, kTrailerBytes> trailer{};
  if (!auth_.MakeTrailer(Bytes(payload), trailer)) throw std::runtime_error("HMAC-SHA256 failed (OpenSSL)");
  payload.append(reinterpret_cast<const char*>(trailer.data()), trailer.size());
  return payload;
}

sim::JournalSigner::Verdict HmacJournalSigner::Check(std::string_view payload, size_t* body_size) {
  std::span<const uint8_t> body;
  switch (auth_.Check(Bytes(payload), &body)) {
    case AuthVerdict::kOk:
      *body_size = body.size();
      return Verdict::kOk;
    case AuthVerdict::kUnsigned:
      return Verdict::kUnsigned;
    default:
      return Verdict::kForged;
  }
}

}  // namespace cutsim::transport

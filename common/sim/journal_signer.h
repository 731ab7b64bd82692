#pragma once
/// @file
/// The event journal's authentication under the session key, as an
/// interface: the journal (event_journal.h) signs every record it writes
/// and checks every record it reads through it, and never sees the key or
/// the MAC. The implementation is the streams' HMAC-SHA256 with its signed
/// trailer (transport::HmacJournalSigner, common/transport/journal_auth.h).

#include <string>
#include <string_view>

namespace cutsim::sim {

class JournalSigner {
 public:
  enum class Verdict { kOk, kUnsigned, kForged };

  virtual ~JournalSigner() = default;

  /// `payload` (a serialised journal header or record) with its tag
  /// appended, still a valid message of its type.
  [[nodiscard]] virtual std::string Sign(std::string payload) = 0;

  /// Checks a signed `payload`: kOk with `*body_size` the bytes the tag
  /// covers (the message without its tag), kUnsigned when it carries no
  /// tag, kForged when the tag does not match (altered, or another key).
  [[nodiscard]] virtual Verdict Check(std::string_view payload, size_t* body_size) = 0;
};

}  // namespace cutsim::sim

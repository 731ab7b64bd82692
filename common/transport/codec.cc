#include "common/transport/codec.h"

#include <algorithm>
#include <climits>

#include <fmt/format.h>

namespace cutsim::transport {

std::string DecodeError::Message() const {
  const std::string_view where = source.empty() ? std::string_view("<unnamed source>") : source;
  switch (status) {
    case DecodeStatus::kOk:
      return fmt::format("{}: {}: ok ({} bytes)", where, type_name, size);
    case DecodeStatus::kTooLarge:
      return fmt::format("{}: {}: payload of {} bytes exceeds the {}-byte limit for this type",
                         where, type_name, size, limit);
    case DecodeStatus::kMalformed:
      return fmt::format(
          "{}: {}: malformed payload ({} bytes): not a valid encoding of this type "
          "(garbage, truncated, or a different message type)",
          where, type_name, size);
  }
  return fmt::format("{}: {}: unknown decode status", where, type_name);
}

namespace detail {

bool DecodeInto(std::span<const uint8_t> bytes, google::protobuf::MessageLite& out,
                std::string_view type_name, size_t limit, std::string_view source,
                DecodeError* err) noexcept {
  auto fail = [&](DecodeStatus status) {
    if (err != nullptr) {
      *err = DecodeError{.status = status,
                         .source = source,
                         .type_name = type_name,
                         .size = bytes.size(),
                         .limit = limit};
    }
    return false;
  };
  if (bytes.size() > limit || bytes.size() > static_cast<size_t>(INT_MAX)) {
    return fail(DecodeStatus::kTooLarge);
  }
  try {
    // ParseFromArray clears `out` first, fails on any malformed or truncated
    // field and on nesting deeper than protobuf's recursion limit (100).
    if (!out.ParseFromArray(bytes.data(), static_cast<int>(bytes.size()))) {
      return fail(DecodeStatus::kMalformed);
    }
  } catch (...) {
    // Only std::bad_alloc can escape protobuf's parser; treat it as a bad
    // payload rather than letting it out of a transport callback.
    return fail(DecodeStatus::kMalformed);
  }
  if (err != nullptr) *err = DecodeError{};
  return true;
}

}  // namespace detail

std::optional<std::span<const uint8_t>> Encoder::Encode(const google::protobuf::MessageLite& msg,
                                                        size_t limit, size_t* size,
                                                        PayloadAuthenticator* signer) {
  const size_t body = msg.ByteSizeLong();
  const size_t n = body + (signer != nullptr ? kTrailerBytes : 0);
  if (size != nullptr) *size = n;
  if (n > limit || n > static_cast<size_t>(INT_MAX)) return std::nullopt;
  if (buffer_.size() < n || buffer_.empty()) buffer_.resize(std::max<size_t>(n, 1));
  // ByteSizeLong cached the sizes; serialise straight into our buffer.
  msg.SerializeWithCachedSizesToArray(buffer_.data());
  if (signer != nullptr &&
      !signer->MakeTrailer({buffer_.data(), body},
                           std::span<uint8_t, kTrailerBytes>(buffer_.data() + body, kTrailerBytes))) {
    return std::nullopt;
  }
  return std::span<const uint8_t>(buffer_.data(), n);
}

}  // namespace cutsim::transport

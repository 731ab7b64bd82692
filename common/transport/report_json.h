#pragma once
/// @file
/// Prints the applications' reports (cutsim/v1/report.proto) as one-line
/// JSON with protobuf's printer: field names as in the .proto, every field
/// present, strings escaped (quotes, control characters, newlines), invalid
/// UTF-8 replaced by U+FFFD, and non-finite doubles as the strings "NaN",
/// "Infinity", "-Infinity", so the output is valid JSON for any input. Every
/// JSON the applications print comes from here.

#include <concepts>
#include <cstdint>
#include <limits>
#include <string>
#include <string_view>

#include <google/protobuf/message.h>

namespace cutsim::transport {

/// `text` with every byte that is not part of a valid UTF-8 sequence
/// (overlong forms and surrogates included) replaced by U+FFFD.
[[nodiscard]] std::string ValidUtf8(std::string_view text);

/// The report as compact one-line JSON (no trailing newline). Never throws;
/// "{}" if the printer fails (it does not for the report messages).
[[nodiscard]] std::string ReportJson(const google::protobuf::Message& report);

/// `n` as a report count: uint32 (which JSON prints as a number, unlike
/// 64-bit integers), saturated to [0, 2^32 − 1].
template <std::integral T>
[[nodiscard]] constexpr uint32_t ReportCount(T n) {
  if constexpr (std::is_signed_v<T>) {
    if (n < 0) return 0;
  }
  constexpr auto kMax = std::numeric_limits<uint32_t>::max();
  return static_cast<std::make_unsigned_t<T>>(n) > kMax ? kMax : static_cast<uint32_t>(n);
}

/// A 64-bit hash as 16 lower-case hex digits.
[[nodiscard]] std::string HexHash(uint64_t hash);

}  // namespace cutsim::transport

#pragma once
/// @file
/// Prints the applications' reports (cutsim/v1/report.proto) as one-line
/// JSON with protobuf's printer: field names as in the .proto, every field
/// present, strings escaped and non-finite doubles as "NaN" / "Infinity", so
/// the output is always valid JSON.

#include <concepts>
#include <cstdint>
#include <limits>
#include <string>

#include <google/protobuf/message.h>

namespace cutsim::transport {

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

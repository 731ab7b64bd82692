#pragma once
/// @file
/// Non-finite values (NaN, ±∞) are refused at the edge, by every reader and
/// validator, with the field named; past the readers, values are trusted.

#include <cmath>
#include <span>
#include <string_view>

#include <fmt/format.h>

#include "common/core/error.h"

namespace cutsim {

/// Throws `InputError` at `where` ("<what> is NaN or infinite") unless `value`
/// is finite.
inline void RequireFinite(double value, const SourceRef& where, std::string_view what = "value") {
  if (!std::isfinite(value)) [[unlikely]] {
    ThrowInputError(where, fmt::format("{} is NaN or infinite", what));
  }
}

/// True if every value is finite.
[[nodiscard]] inline bool AllFinite(std::span<const double> values) {
  for (const double v : values) {
    if (!std::isfinite(v)) return false;
  }
  return true;
}

/// Throws `InputError` at `where` unless `value` is finite and integral and
/// lies in [lo, hi]: for indices and counts read as floating point, which are
/// checked before they are converted or used.
inline int64_t RequireIndex(double value, int64_t lo, int64_t hi, const SourceRef& where,
                            std::string_view what = "index") {
  if (!(std::isfinite(value) && value == std::floor(value) && value >= static_cast<double>(lo) &&
        value <= static_cast<double>(hi))) [[unlikely]] {
    ThrowInputError(where, fmt::format("{} {:g} is not an integer in [{}, {}]", what, value, lo, hi));
  }
  return static_cast<int64_t>(value);
}

}  // namespace cutsim

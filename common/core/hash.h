#pragma once
/// @file
/// FNV-1a 64: a byte hash for integrity and identity checks (checkpoint
/// bodies, scene fingerprints, before/after result hashes in tests and
/// benchmarks) — against mistakes, not an attacker.

#include <cstddef>
#include <cstdint>

namespace cutsim {

/// FNV-1a 64 of `size` bytes, continuing from `basis` (FNV's offset basis by
/// default), so a hash can be chained over several buffers.
[[nodiscard]] inline uint64_t Fnv1a64(const void* data, size_t size, uint64_t basis = 0xcbf29ce484222325ULL) {
  const auto* bytes = static_cast<const unsigned char*>(data);
  uint64_t h = basis;
  for (size_t i = 0; i < size; ++i) {
    h ^= bytes[i];
    h *= 0x100000001b3ULL;
  }
  return h;
}

}  // namespace cutsim

#pragma once
// Private helper: hashing of sorted triangle keys for O(T) face matching.

#include <algorithm>
#include <array>
#include <cstddef>
#include <cstdint>

namespace cutsim::mesh::internal {

/// Local faces of a positively oriented tet, ordered so that each triangle is
/// counter-clockwise seen from outside; face f is opposite node f.
inline constexpr std::array<std::array<int, 3>, 4> kTetFaces = {
    {{1, 2, 3}, {0, 3, 2}, {0, 1, 3}, {0, 2, 1}}};

using FaceKey = std::array<int32_t, 3>;

inline FaceKey SortedKey(int32_t a, int32_t b, int32_t c) {
  if (a > b) std::swap(a, b);
  if (b > c) std::swap(b, c);
  if (a > b) std::swap(a, b);
  return {a, b, c};
}

struct FaceKeyHash {
  std::size_t operator()(const FaceKey& k) const noexcept {
    // splitmix-style mixing of the three indices.
    uint64_t h = static_cast<uint64_t>(static_cast<uint32_t>(k[0]));
    h = h * 0x9E3779B97F4A7C15ULL ^ static_cast<uint32_t>(k[1]);
    h = h * 0xBF58476D1CE4E5B9ULL ^ static_cast<uint32_t>(k[2]);
    h ^= h >> 31;
    h *= 0x94D049BB133111EBULL;
    h ^= h >> 29;
    return static_cast<std::size_t>(h);
  }
};

}  // namespace cutsim::mesh::internal

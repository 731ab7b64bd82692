#include "common/transport/mesh_hash.h"

#include <algorithm>
#include <cmath>
#include <cstdlib>

namespace cutsim::transport {

int32_t Quantise(double x, double quantum) {
  const double k = std::nearbyint(x / quantum);
  if (!(k == k)) return 0;  // NaN
  return static_cast<int32_t>(std::clamp(k, -static_cast<double>(kMaxQuantised),
                                         static_cast<double>(kMaxQuantised)));
}

namespace {
constexpr double kStressStepsPerOctave = 16.0;
constexpr int32_t kMaxStressCode = 65535;
}  // namespace

int32_t StressCode(double s) {
  if (!(s == s)) return 0;
  const double mag = std::min(kStressStepsPerOctave * std::log2(1.0 + std::fabs(s)),
                              static_cast<double>(kMaxStressCode));
  const auto c = static_cast<int32_t>(std::nearbyint(mag));
  return s < 0 ? -c : c;
}

double StressFromCode(int32_t code) {
  const double mag = std::exp2(std::abs(code) / kStressStepsPerOctave) - 1.0;
  return code < 0 ? -mag : mag;
}

namespace {

// A simple 64-bit streaming hash over integer words (multiply-xorshift per
// word, FNV offset basis as seed). Integrity against bugs and corruption, not
// an adversary. Works on values, not bytes, so it is endian-independent.
class Hasher {
 public:
  void Word(uint64_t w) {
    h_ ^= w;
    h_ *= 0x9E3779B97F4A7C15ULL;
    h_ ^= h_ >> 29;
  }
  void Ints(const int32_t* p, size_t n) {
    size_t i = 0;
    for (; i + 1 < n; i += 2) {
      Word(static_cast<uint64_t>(static_cast<uint32_t>(p[i])) |
           (static_cast<uint64_t>(static_cast<uint32_t>(p[i + 1])) << 32));
    }
    if (i < n) Word(static_cast<uint32_t>(p[i]));
  }
  [[nodiscard]] uint64_t Final() const {
    uint64_t h = h_;
    h ^= h >> 33;
    h *= 0xFF51AFD7ED558CCDULL;
    h ^= h >> 33;
    return h;
  }

 private:
  uint64_t h_ = 0xCBF29CE484222325ULL;
};

}  // namespace

uint64_t TopologyHash(uint64_t topology_version, const mesh::Tets& tets,
                      const mesh::Triangles& surface, std::span<const uint8_t> opened) {
  Hasher h;
  h.Word(0x544F504FULL);  // "TOPO"
  h.Word(topology_version);
  h.Word(static_cast<uint64_t>(tets.rows()));
  h.Ints(tets.data(), static_cast<size_t>(tets.size()));
  h.Word(static_cast<uint64_t>(surface.rows()));
  h.Ints(surface.data(), static_cast<size_t>(surface.size()));
  // Opened flags as bits, 64 per word; empty hashes like all zeros.
  const auto faces = static_cast<size_t>(surface.rows());
  for (size_t base = 0; base < faces; base += 64) {
    uint64_t bits = 0;
    if (!opened.empty()) {
      for (size_t i = base; i < std::min(faces, base + 64); ++i) {
        if (i < opened.size() && opened[i] != 0) bits |= uint64_t{1} << (i - base);
      }
    }
    h.Word(bits);
  }
  return h.Final();
}

uint64_t PositionsHash(const QuantisedPositions& world_q) {
  Hasher h;
  h.Word(0x504F53ULL);  // "POS"
  h.Word(static_cast<uint64_t>(world_q.rows()));
  h.Ints(world_q.data(), static_cast<size_t>(world_q.size()));
  return h.Final();
}

uint64_t CombineHashes(uint64_t topology_hash, uint64_t positions_hash) {
  Hasher h;
  h.Word(topology_hash);
  h.Word(positions_hash);
  return h.Final();
}

uint64_t MeshHash(uint64_t topology_version, const QuantisedPositions& world_q,
                  const mesh::Tets& tets, const mesh::Triangles& surface,
                  std::span<const uint8_t> opened) {
  return CombineHashes(TopologyHash(topology_version, tets, surface, opened),
                       PositionsHash(world_q));
}

}  // namespace cutsim::transport

// The observer stream as a viewer receives it: a sequence of samples
// (snapshot, delta, status payloads) fed to a fresh MeshStreamSubscriber,
// keyed for odd first bytes (only signed samples pass) and open for even
// ones (every payload reaches the parser, the epoch gate and the replica).
//
// Input: [mode:1] then records of [kind:1][length:2, little endian][payload].
#include <unistd.h>

#include <algorithm>
#include <cstddef>
#include <cstdint>
#include <memory>
#include <optional>
#include <span>
#include <string>

#include "common/transport/dds.h"
#include "common/transport/mesh_stream.h"
#include "cutsim/v1/wire.pb.h"

namespace {

uint64_t SeqOf(cutsim::transport::EnvelopeKind kind, std::span<const uint8_t> payload) {
  using cutsim::transport::EnvelopeKind;
  const auto* data = payload.data();
  const int size = static_cast<int>(payload.size());
  switch (kind) {
    case EnvelopeKind::kSnapshot: {
      cutsim::v1::MeshSnapshot m;
      return m.ParseFromArray(data, size) ? m.seq() : 0;
    }
    case EnvelopeKind::kDelta: {
      cutsim::v1::MeshDelta m;
      return m.ParseFromArray(data, size) ? m.seq() : 0;
    }
    case EnvelopeKind::kStatus:
      return 1;
    case EnvelopeKind::kControl: {
      cutsim::v1::DebriefControl m;
      return m.ParseFromArray(data, size) ? m.seq() : 0;
    }
  }
  return 0;
}

}  // namespace

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
  using namespace cutsim::transport;
  static DdsParticipant participant(1 + static_cast<uint32_t>(::getpid()) % 200);
  if (size < 1) return 0;
  std::optional<SessionKey> key;
  if (data[0] % 2 == 1) key = ParseSessionKey(std::string(64, 'f'), "fuzz");
  MeshStreamSubscriber sub(participant, "fuzz", key);
  size_t at = 1;
  while (at + 3 <= size) {
    const auto kind = static_cast<EnvelopeKind>(data[at] % 3);
    const size_t length = std::min<size_t>(data[at + 1] | (size_t{data[at + 2]} << 8), size - at - 3);
    const std::span<const uint8_t> payload(data + at + 3, length);
    sub.Process(kind, "fuzz", SeqOf(kind, payload), payload);
    at += 3 + length;
  }
  return 0;
}

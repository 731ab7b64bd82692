// Second process for the DDS discovery test. Usage:
//   cutsim_dds_peer <domain> <session> <seq>
// Publishes one snapshot envelope (payload: a MeshSnapshot with that seq)
// before any reader exists, with the default (loopback) configuration, then
// waits up to 15 s for a reader to match and up to 15 s more for it to leave
// (the test deletes its reader once it has the snapshot; Cyclone's
// wait-for-acks does not cover a late joiner's replay). Exit code 0 when the
// reader came and went, 2 on timeout, 1 on bad arguments or errors.

#include <chrono>
#include <cstdio>
#include <cstdlib>
#include <exception>
#include <string>

#include "common/transport/codec.h"
#include "common/transport/dds.h"
#include "cutsim/v1/wire.pb.h"

int main(int argc, char** argv) {
  using namespace cutsim::transport;
  if (argc != 4) {
    std::fprintf(stderr, "usage: %s <domain> <session> <seq>\n", argv[0]);
    return 1;
  }
  try {
    const auto domain = static_cast<uint32_t>(std::stoul(argv[1]));
    const std::string session = argv[2];
    const uint64_t seq = std::stoull(argv[3]);
    DdsParticipant participant(domain);
    DdsTopic topic(participant, EnvelopeKind::kSnapshot);
    DdsWriter writer(topic);
    cutsim::v1::MeshSnapshot snap;
    snap.set_session(session);
    snap.set_seq(seq);
    for (int i = 0; i < 12; ++i) snap.add_world(0.5F * static_cast<float>(i));
    Encoder encoder;
    const auto bytes = encoder.Encode(snap);
    if (!bytes || writer.Publish(EnvelopeKind::kSnapshot, seq, session, *bytes) != DdsPublishStatus::kOk) {
      std::fprintf(stderr, "cutsim_dds_peer: publish failed\n");
      return 1;
    }
    if (!writer.WaitForReaders(1, std::chrono::seconds(15))) {
      std::fprintf(stderr, "cutsim_dds_peer: no reader matched\n");
      return 2;
    }
    if (!writer.WaitForNoReaders(std::chrono::seconds(15))) {
      std::fprintf(stderr, "cutsim_dds_peer: reader did not leave\n");
      return 2;
    }
    return 0;
  } catch (const std::exception& e) {
    std::fprintf(stderr, "cutsim_dds_peer: %s\n", e.what());
    return 1;
  }
}

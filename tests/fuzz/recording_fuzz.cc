// Recordings: the LCM log format event by event, and each event's payload
// decoded as the record message its channel names.
#include <cstddef>
#include <cstdint>
#include <span>

#include "common/core/error.h"
#include "common/core/log.h"
#include "common/transport/codec.h"
#include "common/transport/lcm_log.h"
#include "cutsim/v1/wire.pb.h"
#include "tests/fuzz/fuzz_util.h"

extern "C" int LLVMFuzzerInitialize(int*, char***) {
  cutsim::Log().set_level(spdlog::level::off);
  return 0;
}

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
  using namespace cutsim;
  try {
    transport::LcmLogReader reader(fuzz::WriteInput(data, size, "f.lcm"));
    int events = 0;
    while (auto e = reader.Next()) {
      if (++events > 10000) break;
      const std::span<const uint8_t> bytes(e->data);
      if (e->channel.ends_with("_REC_HEADER")) {
        (void)transport::Decode<v1::RecordHeader>(bytes, e->channel);
      } else if (e->channel.ends_with("_REC_FRAME")) {
        (void)transport::Decode<v1::RecordFrame>(bytes, e->channel);
      } else {
        (void)transport::Decode<v1::RecordEnd>(bytes, e->channel);
      }
    }
  } catch (const InputError&) {
  }
  return 0;
}

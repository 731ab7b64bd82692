// Wire messages: protobuf decoding with the size caps of codec.h, then the
// validation each receiver applies (the haptic model's plausibility checks,
// the tool sample conversion).
#include <cstddef>
#include <cstdint>
#include <span>

#include "common/haptics/local_model.h"
#include "common/transport/codec.h"
#include "common/transport/haptic_link.h"
#include "cutsim/v1/wire.pb.h"

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
  using namespace cutsim;
  if (size < 1) return 0;
  const std::span<const uint8_t> bytes(data + 1, size - 1);
  if (data[0] % 2 == 0) {
    v1::HapticModel msg;
    if (!transport::DecodeInto(bytes, msg, "fuzz")) return 0;
    haptics::LocalModel model;
    if (transport::FromProto(msg, &model)) (void)haptics::Validate(model);
  } else {
    v1::ToolState msg;
    if (!transport::DecodeInto(bytes, msg, "fuzz")) return 0;
    (void)transport::FromProto(msg);
  }
  return 0;
}

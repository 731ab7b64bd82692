// Scene text: parse and validate (no mesh is built: generators are bounded
// by the validation, which is what this target exercises).
#include <cstddef>
#include <cstdint>
#include <string>

#include "common/core/error.h"
#include "common/sim/scene_loader.h"

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
  try {
    (void)cutsim::sim::ParseScene(std::string(reinterpret_cast<const char*>(data), size), "fuzz.pbtxt", "/nonexistent");
  } catch (const cutsim::InputError&) {
  }
  return 0;
}

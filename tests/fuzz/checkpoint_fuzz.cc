// Checkpoint files: the outer envelope (magic, version, checksum), and, for
// inputs that pass it, a restore into a small cut-enabled scene.
#include <cstddef>
#include <cstdint>
#include <memory>

#include "common/core/error.h"
#include "common/core/log.h"
#include "common/sim/checkpoint.h"
#include "common/sim/scene_loader.h"
#include "common/sim/simulation.h"
#include "tests/fuzz/fuzz_util.h"

extern "C" int LLVMFuzzerInitialize(int*, char***) {
  cutsim::Log().set_level(spdlog::level::off);
  return 0;
}

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
  using namespace cutsim;
  static const sim::LoadedScene scene = sim::ParseScene(fuzz::kCutScene, "fuzz.pbtxt", "/nonexistent");
  const std::string path = fuzz::WriteInput(data, size, "f.ckpt");
  try {
    (void)sim::ReadCheckpointFile(path);
  } catch (const InputError&) {
    return 0;
  }
  try {
    auto simulation = sim::Simulation::Create(scene);
    sim::RestoreCheckpoint(*simulation, path);
  } catch (const InputError&) {
  }
  return 0;
}

// Event journals: the record frames (lengths, checksums, torn tails,
// corruption), and, for inputs that pass, a resume of a small cut-enabled
// scene from the journal alone (identity, lineage, every event checked
// before it is applied).
#include <cstddef>
#include <cstdint>
#include <filesystem>
#include <memory>

#include "common/core/error.h"
#include "common/core/log.h"
#include "common/sim/checkpointer.h"
#include "common/sim/event_journal.h"
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
  // The journal of a checkpoint that does not exist ("j.ckpt").
  const std::filesystem::path path = fuzz::WriteInput(data, size, "j.ckpt.journal");
  const std::filesystem::path checkpoint = path.parent_path() / "j.ckpt";
  try {
    (void)sim::ReadJournalFile(path);
  } catch (const InputError&) {
    return 0;
  }
  try {
    auto simulation = sim::Simulation::Create(scene);
    sim::PeriodicCheckpointer checkpointer(checkpoint, 0.0);
    (void)checkpointer.Begin(*simulation, /*resume=*/true);
  } catch (const InputError&) {
  }
  return 0;
}

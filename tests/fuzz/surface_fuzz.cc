// Closed surfaces (STL, OBJ) up to gmsh: the first byte picks the format.
// A coarse edge length keeps gmsh's part small.
#include <cstddef>
#include <cstdint>

#include "common/core/error.h"
#include "common/core/log.h"
#include "common/mesh/generators.h"
#include "tests/fuzz/fuzz_util.h"

extern "C" int LLVMFuzzerInitialize(int*, char***) {
  cutsim::Log().set_level(spdlog::level::off);
  return 0;
}

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
  if (size < 1 || size > 4096) return 0;
  const bool obj = data[0] % 2 == 0;
  try {
    (void)cutsim::mesh::TetrahedralizeSurface(
        cutsim::fuzz::WriteInput(data + 1, size - 1, obj ? "f.obj" : "f.stl"), 0.5);
  } catch (const cutsim::InputError&) {
  }
  return 0;
}

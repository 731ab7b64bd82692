// Mesh files: the first byte picks the reader (msh, TetGen, Medit, VTU), the
// rest is the file. TetGen gets the rest split at the first NUL into .node
// and .ele.
#include <cstddef>
#include <cstdint>
#include <string>

#include "common/core/error.h"
#include "common/mesh/mesh_io.h"
#include "common/core/log.h"
#include "tests/fuzz/fuzz_util.h"

extern "C" int LLVMFuzzerInitialize(int*, char***) {
  cutsim::Log().set_level(spdlog::level::off);
  return 0;
}

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
  if (size < 1) return 0;
  const uint8_t kind = data[0] % 4;
  ++data;
  --size;
  using namespace cutsim;
  try {
    switch (kind) {
      case 0:
        (void)mesh::ReadGmsh(fuzz::WriteInput(data, size, "f.msh"));
        break;
      case 1: {
        const std::string s(reinterpret_cast<const char*>(data), size);
        const size_t nul = s.find('\0');
        const std::string node = s.substr(0, nul), ele = nul == std::string::npos ? "" : s.substr(nul + 1);
        fuzz::WriteInput(reinterpret_cast<const uint8_t*>(ele.data()), ele.size(), "f.ele");
        (void)mesh::ReadTetGen(
            fuzz::WriteInput(reinterpret_cast<const uint8_t*>(node.data()), node.size(), "f.node"));
        break;
      }
      case 2:
        (void)mesh::ReadMedit(fuzz::WriteInput(data, size, "f.mesh"));
        break;
      default:
        (void)mesh::ReadVtu(fuzz::WriteInput(data, size, "f.vtu"));
        break;
    }
  } catch (const InputError&) {
  }
  return 0;
}

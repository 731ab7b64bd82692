// Tool path text.
#include <cstddef>
#include <cstdint>
#include <string>

#include "common/core/error.h"
#include "common/haptics/tool_path.h"

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
  try {
    const auto path =
        cutsim::haptics::ToolPath::Parse(std::string(reinterpret_cast<const char*>(data), size), "fuzz.path");
    (void)path;
  } catch (const cutsim::InputError&) {
  }
  return 0;
}

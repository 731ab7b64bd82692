#pragma once
// Shared by the libFuzzer targets: readers that take a path get the input
// through a per-process temp file; InputError is the expected answer to bad
// input, anything else (a crash, an abort, a sanitizer report, another
// exception) is a finding.

#include <unistd.h>

#include <cstddef>
#include <cstdint>
#include <filesystem>
#include <fstream>
#include <string>

namespace cutsim::fuzz {

/// The smallest cut-enabled scene (two box cells and a tool): what the
/// checkpoint and journal targets restore their inputs into.
inline constexpr const char* kCutScene = R"pb(name: "fuzz"
mesh { box { min { x: 0 y: 0 z: 0 } max { x: 0.02 y: 0.01 z: 0.01 } nx: 2 ny: 1 nz: 1 } }
materials { young_poisson { youngs_modulus: 20000 poisson_ratio: 0.4 } density: 1000 }
time_step { threads: 1 }
tool { keyframes { t: 0 tip { x: 0 } blade_dir { z: 1 } } }
cutting { enabled: true alpha: 0.4 kappa: 1 zeta: 1 }
)pb";

/// Writes `data` to a file named `name` in this process's temp directory;
/// returns its path.
inline std::string WriteInput(const uint8_t* data, size_t size, const std::string& name) {
  static const std::filesystem::path dir = [] {
    auto d = std::filesystem::temp_directory_path() / ("cutsim-fuzz-" + std::to_string(::getpid()));
    std::filesystem::create_directories(d);
    return d;
  }();
  const std::string path = (dir / name).string();
  std::ofstream(path, std::ios::binary | std::ios::trunc).write(reinterpret_cast<const char*>(data),
                                                                 static_cast<std::streamsize>(size));
  return path;
}

}  // namespace cutsim::fuzz

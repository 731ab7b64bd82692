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

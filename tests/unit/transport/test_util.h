#pragma once
// Per-process names for transport tests, so that parallel test processes
// (ctest -j) never hear each other: a DDS domain and a session derived from
// the pid, and a counter for several sessions in one process.

#include <unistd.h>

#include <atomic>
#include <cstdint>
#include <string>

namespace cutsim::transport::testing {

/// A DDS domain id in 1..200 derived from the pid (ports stay below 65535).
inline uint32_t TestDomainId() { return 1 + static_cast<uint32_t>(getpid()) % 200; }

/// A session name unique to this process and call.
inline std::string UniqueSession(const char* tag) {
  static std::atomic<int> counter{0};
  return std::string(tag) + "_" + std::to_string(getpid()) + "_" + std::to_string(counter++);
}

}  // namespace cutsim::transport::testing

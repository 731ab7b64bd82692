// The lab list as a bridge builds it from the network: status payloads of
// any session fed to a SessionDirectory (capped small, so the cap is
// exercised), then the list's JSON. Every input is either dropped (counted)
// or listed; the list never holds more sessions than the cap, and its JSON
// is printable ASCII that starts and ends as an object.
//
// Input: records of [session length:1][session][payload length:2, little
// endian][payload][clock step:1, in 0.1 s].
#include <cstddef>
#include <cstdint>
#include <cstdlib>
#include <span>
#include <string>
#include <vector>

#include "common/transport/session_directory.h"
#include "common/web/lab_bridge.h"

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
  using namespace cutsim;
  constexpr size_t kCap = 4;
  transport::SessionDirectory dir(transport::SessionDirectoryOptions{.max_sessions = kCap});
  int64_t now = 0;
  size_t at = 0;
  while (at < size) {
    const size_t name_len = data[at++];
    if (at + name_len + 2 > size) break;
    const std::string session(reinterpret_cast<const char*>(data + at), name_len);
    at += name_len;
    const size_t len = data[at] | (static_cast<size_t>(data[at + 1]) << 8);
    at += 2;
    if (at + len > size) break;
    (void)dir.Process(session, std::span<const uint8_t>(data + at, len), now);
    at += len;
    if (at < size) now += static_cast<int64_t>(data[at++]) * 100'000'000;
  }
  std::vector<web::LabSessionView> views;
  for (const transport::SessionEntry& e : dir.Entries(now)) views.push_back({.entry = e});
  if (views.size() > kCap) std::abort();
  const std::string json = web::LabListJson(views, false);
  if (json.empty() || json.front() != '{' || json.back() != '}') std::abort();
  for (const char c : json) {
    if (c < 0x20 || c > 0x7e) std::abort();
  }
  return 0;
}

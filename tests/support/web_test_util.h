#pragma once
/// @file
/// What the web servers' unit tests share: a page file in a temporary
/// directory, outgoing messages, and a bounded wait for the I/O thread.

#include <unistd.h>

#include <chrono>
#include <filesystem>
#include <fstream>
#include <map>
#include <memory>
#include <string>
#include <thread>

#include "common/web/observer_server.h"

namespace cutsim::test {

/// `index.html` holding `html`, in a directory of its own (named after
/// `tag` and the process) that is removed with the object.
class TempPage {
 public:
  explicit TempPage(const std::string& tag = "page", const std::string& html = "<html>page</html>")
      : dir_(std::filesystem::temp_directory_path() / ("cutsim_" + tag + "_" + std::to_string(::getpid()))) {
    std::filesystem::create_directories(dir_);
    std::ofstream(dir_ / "index.html") << html;
  }
  ~TempPage() { std::filesystem::remove_all(dir_); }
  TempPage(const TempPage&) = delete;
  TempPage& operator=(const TempPage&) = delete;
  [[nodiscard]] std::map<std::string, std::filesystem::path> files() const { return {{"/index.html", dir_ / "index.html"}}; }

 private:
  std::filesystem::path dir_;
};

/// An outgoing text or binary message.
inline web::Outgoing Text(const std::string& s) { return {std::make_shared<const std::string>(s), false}; }
inline web::Outgoing Binary(const std::string& s) { return {std::make_shared<const std::string>(s), true}; }

/// Waits up to 5 s until `pred` holds (a server's I/O thread updates what
/// it reads); returns whether it did.
template <typename P>
bool Eventually(P pred) {
  using namespace std::chrono_literals;
  const auto deadline = std::chrono::steady_clock::now() + 5s;
  while (std::chrono::steady_clock::now() < deadline) {
    if (pred()) return true;
    std::this_thread::sleep_for(5ms);
  }
  return pred();
}

}  // namespace cutsim::test

#pragma once
/// @file
/// Starts real processes for integration tests: argv in, exit code and
/// captured stdout/stderr out, with a hard timeout so a hung process fails the
/// test instead of hanging CI. RAII: a still-running child is killed when its
/// Subprocess goes out of scope.

#include <sys/types.h>

#include <chrono>
#include <functional>
#include <map>
#include <optional>
#include <string>
#include <vector>

namespace cutsim::testing {

class Subprocess {
 public:
  /// Starts `argv[0]` with `argv`, extra environment variables `env`,
  /// stdout/stderr captured to files under a temporary directory.
  Subprocess(std::vector<std::string> argv, std::map<std::string, std::string> env = {});
  ~Subprocess();
  Subprocess(const Subprocess&) = delete;
  Subprocess& operator=(const Subprocess&) = delete;

  /// Waits up to `timeout`; returns the exit code, or nullopt on timeout
  /// (the process is then left running; the destructor kills it).
  std::optional<int> Wait(std::chrono::milliseconds timeout);
  /// Sends `signal` (default SIGTERM) if still running.
  void Signal(int signal);
  /// Kills and reaps.
  void Kill();
  [[nodiscard]] bool running();
  [[nodiscard]] pid_t pid() const { return pid_; }

  [[nodiscard]] std::string Stdout() const;
  [[nodiscard]] std::string Stderr() const;

 private:
  pid_t pid_ = -1;
  std::optional<int> exit_code_;
  std::string out_path_;
  std::string err_path_;
};

/// Runs to completion (or timeout → failure recorded as exit code -1).
struct RunResult {
  int exit_code = -1;
  std::string out;
  std::string err;
};
RunResult RunProcess(std::vector<std::string> argv, std::chrono::milliseconds timeout,
              std::map<std::string, std::string> env = {});

/// Readiness waits: poll a condition with a deadline instead of sleeping a
/// fixed time, so a test neither races a slow start on a loaded machine nor
/// waits longer than it must on a quiet one.
///
/// Polls `condition` every `poll` until it holds (true) or `timeout` passes
/// (false; the condition is checked once more at the deadline).
bool WaitUntil(const std::function<bool()>& condition, std::chrono::milliseconds timeout,
               std::chrono::milliseconds poll = std::chrono::milliseconds(10));

/// Waits until `process`'s stderr contains `text` (a log line it writes when
/// ready); false on timeout or when the process exits without writing it.
bool WaitForStderr(Subprocess& process, const std::string& text, std::chrono::milliseconds timeout);

/// Number of complete lines in a file (0 if missing); for logs written a line
/// at a time (e.g. the viewer's --frame-log).
size_t CountLines(const std::string& path);

/// Whether a UDP socket of this network namespace is bound to `port`
/// (/proc/net/udp and udp6): a subscriber has opened its receive socket.
bool UdpPortBound(int port);

/// Whether a socket of this network namespace has joined the IPv4 multicast
/// group `address` (dotted quad) on some interface (/proc/net/igmp): a udpm
/// subscriber receives the group's datagrams from then on.
bool MulticastGroupJoined(const std::string& address);

/// Path to an executable in <build>/bin.
std::string BinPath(const std::string& name);

/// A temporary directory removed on destruction.
class TempDir {
 public:
  explicit TempDir(const std::string& prefix = "cutsim");
  ~TempDir();
  TempDir(const TempDir&) = delete;
  TempDir& operator=(const TempDir&) = delete;
  [[nodiscard]] const std::string& path() const { return path_; }

 private:
  std::string path_;
};

/// A number unique to this test process for DDS domain ids / LCM ports.
int UniqueTestIndex();

/// The number after `"key":` (optional whitespace between) in a flat JSON
/// text (NaN if absent or not a number): enough for the one-line summaries
/// the apps print. The first occurrence of the key wins.
double JsonNumber(const std::string& json, const std::string& key);

/// The string after `"key":` (optional whitespace), without its quotes and
/// with no unescaping; nullopt if absent or not a string.
std::optional<std::string> JsonString(const std::string& json, const std::string& key);

/// The `true`/`false` after `"key":` (optional whitespace); nullopt if absent
/// or not a boolean.
std::optional<bool> JsonBool(const std::string& json, const std::string& key);

/// The whole text of a file ("" if missing).
std::string ReadTextFile(const std::string& path);

}  // namespace cutsim::testing

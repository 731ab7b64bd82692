#include "tests/integration/subprocess.h"

#include <fcntl.h>
#include <signal.h>
#include <sys/wait.h>
#include <unistd.h>

#include <algorithm>
#include <atomic>
#include <cctype>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <sstream>
#include <stdexcept>
#include <thread>

namespace cutsim::testing {
namespace {

std::string ReadFile(const std::string& path) {
  std::ifstream in(path, std::ios::binary);
  std::ostringstream s;
  s << in.rdbuf();
  return s.str();
}

std::string MakeTempName(const std::string& prefix) {
  static std::atomic<int> counter{0};
  return (std::filesystem::temp_directory_path() /
          (prefix + "-" + std::to_string(::getpid()) + "-" + std::to_string(counter++)))
      .string();
}

}  // namespace

Subprocess::Subprocess(std::vector<std::string> argv, std::map<std::string, std::string> env) {
  const std::string base = MakeTempName("cutsim-proc");
  out_path_ = base + ".out";
  err_path_ = base + ".err";
  std::vector<char*> args;
  for (auto& a : argv) args.push_back(a.data());
  args.push_back(nullptr);
  pid_ = ::fork();
  if (pid_ < 0) throw std::runtime_error("fork failed");
  if (pid_ == 0) {
    const int out = ::open(out_path_.c_str(), O_WRONLY | O_CREAT | O_TRUNC, 0644);
    const int err = ::open(err_path_.c_str(), O_WRONLY | O_CREAT | O_TRUNC, 0644);
    ::dup2(out, 1);
    ::dup2(err, 2);
    const int null_in = ::open("/dev/null", O_RDONLY);
    ::dup2(null_in, 0);
    for (const auto& [k, v] : env) ::setenv(k.c_str(), v.c_str(), 1);
    ::execv(args[0], args.data());
    ::_exit(127);
  }
}

Subprocess::~Subprocess() {
  Kill();
  std::error_code ec;
  std::filesystem::remove(out_path_, ec);
  std::filesystem::remove(err_path_, ec);
}

std::optional<int> Subprocess::Wait(std::chrono::milliseconds timeout) {
  if (exit_code_) return exit_code_;
  const auto deadline = std::chrono::steady_clock::now() + timeout;
  while (true) {
    int status = 0;
    const pid_t r = ::waitpid(pid_, &status, WNOHANG);
    if (r == pid_) {
      exit_code_ = WIFEXITED(status) ? WEXITSTATUS(status) : 128 + WTERMSIG(status);
      return exit_code_;
    }
    if (std::chrono::steady_clock::now() >= deadline) return std::nullopt;
    std::this_thread::sleep_for(std::chrono::milliseconds(5));
  }
}

void Subprocess::Signal(int sig) {
  if (!exit_code_ && pid_ > 0) ::kill(pid_, sig);
}

void Subprocess::Kill() {
  if (exit_code_ || pid_ <= 0) return;
  ::kill(pid_, SIGKILL);
  int status = 0;
  ::waitpid(pid_, &status, 0);
  exit_code_ = 128 + SIGKILL;
}

bool Subprocess::running() { return !Wait(std::chrono::milliseconds(0)).has_value(); }

std::string Subprocess::Stdout() const { return ReadFile(out_path_); }
std::string Subprocess::Stderr() const { return ReadFile(err_path_); }

RunResult RunProcess(std::vector<std::string> argv, std::chrono::milliseconds timeout,
              std::map<std::string, std::string> env) {
  Subprocess p(std::move(argv), std::move(env));
  RunResult r;
  const auto code = p.Wait(timeout);
  if (!code) p.Kill();
  r.exit_code = code.value_or(-1);
  r.out = p.Stdout();
  r.err = p.Stderr();
  return r;
}

bool WaitUntil(const std::function<bool()>& condition, std::chrono::milliseconds timeout,
               std::chrono::milliseconds poll) {
  const auto deadline = std::chrono::steady_clock::now() + timeout;
  while (std::chrono::steady_clock::now() < deadline) {
    if (condition()) return true;
    std::this_thread::sleep_for(poll);
  }
  return condition();
}

bool WaitForStderr(Subprocess& process, const std::string& text, std::chrono::milliseconds timeout) {
  const auto written = [&] { return process.Stderr().find(text) != std::string::npos; };
  (void)WaitUntil([&] { return written() || !process.running(); }, timeout);
  return written();
}

size_t CountLines(const std::string& path) {
  const std::string text = ReadFile(path);
  return static_cast<size_t>(std::count(text.begin(), text.end(), '\n'));
}

bool UdpPortBound(int port) {
  char hex[8];
  std::snprintf(hex, sizeof hex, ":%04X", port);
  for (const char* table : {"/proc/net/udp", "/proc/net/udp6"}) {
    std::ifstream in(table);
    std::string line;
    std::getline(in, line);  // header
    while (std::getline(in, line)) {
      std::istringstream fields(line);
      std::string slot, local;
      fields >> slot >> local;  // local address:port, hex
      if (local.size() >= 5 && local.compare(local.size() - 5, 5, hex) == 0) return true;
    }
  }
  return false;
}

bool MulticastGroupJoined(const std::string& address) {
  unsigned a = 0, b = 0, c = 0, d = 0;
  if (std::sscanf(address.c_str(), "%u.%u.%u.%u", &a, &b, &c, &d) != 4) return false;
  char hex[9];
  std::snprintf(hex, sizeof hex, "%02X%02X%02X%02X", d & 0xff, c & 0xff, b & 0xff, a & 0xff);  // as the kernel prints it
  return ReadFile("/proc/net/igmp").find(hex) != std::string::npos;
}

std::string BinPath(const std::string& name) {
  return std::string(CUTSIM_BIN_DIR) + "/" + name;
}

TempDir::TempDir(const std::string& prefix) : path_(MakeTempName(prefix)) {
  std::filesystem::create_directories(path_);
}

TempDir::~TempDir() {
  std::error_code ec;
  std::filesystem::remove_all(path_, ec);
}

namespace {

/// Index of the first character of the value of `"key":` after optional
/// whitespace, or npos.
size_t JsonValueAt(const std::string& json, const std::string& key) {
  const std::string needle = "\"" + key + "\":";
  auto at = json.find(needle);
  if (at == std::string::npos) return std::string::npos;
  at += needle.size();
  while (at < json.size() && std::isspace(static_cast<unsigned char>(json[at])) != 0) ++at;
  return at;
}

}  // namespace

double JsonNumber(const std::string& json, const std::string& key) {
  const size_t at = JsonValueAt(json, key);
  if (at == std::string::npos) return NAN;
  try {
    return std::stod(json.substr(at));
  } catch (const std::exception&) {
    return NAN;
  }
}

std::optional<std::string> JsonString(const std::string& json, const std::string& key) {
  const size_t at = JsonValueAt(json, key);
  if (at == std::string::npos || at >= json.size() || json[at] != '"') return std::nullopt;
  const size_t end = json.find('"', at + 1);
  if (end == std::string::npos) return std::nullopt;
  return json.substr(at + 1, end - at - 1);
}

std::optional<bool> JsonBool(const std::string& json, const std::string& key) {
  const size_t at = JsonValueAt(json, key);
  if (at == std::string::npos) return std::nullopt;
  if (json.compare(at, 4, "true") == 0) return true;
  if (json.compare(at, 5, "false") == 0) return false;
  return std::nullopt;
}

std::string ReadTextFile(const std::string& path) { return ReadFile(path); }

int UniqueTestIndex() {
  // pid-derived, so parallel ctest processes differ; kept in a small range.
  return static_cast<int>(::getpid() % 200) + 20;
}

}  // namespace cutsim::testing

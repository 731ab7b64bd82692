#pragma once
/// @file
/// The server application: command line, then a headless batch run (or, with
/// the haptic link, a real-time session). Thin: the work is in common/.

#include <optional>
#include <string>

namespace cutsim::server {

struct ServerOptions {
  std::string scene;
  bool headless = false;
  std::optional<double> duration;  ///< s of simulated time
  bool until_rest = false;
  double max_time = 600.0;         ///< s, cap on simulated time for --until-rest
  std::string out;                 ///< .vtu of the final state
  int threads = 0;
  std::string precision;
  std::string log_level = "info";
  bool progress = true;
};

class ServerApp {
 public:
  /// Returns -1 to continue, or an exit code (help, version, bad flags).
  int ParseArgs(int argc, char** argv);
  /// Runs what the flags ask; returns the process exit code.
  int Run();

 private:
  int RunHeadless();

  ServerOptions options_;
};

}  // namespace cutsim::server

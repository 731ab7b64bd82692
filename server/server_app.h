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
  // Real-time session (not --headless).
  std::string session = "default";
  std::string lcm_url = "udpm://239.255.76.67:7667?ttl=0";
  uint32_t dds_domain = 0;
  std::string dds_config;          ///< file; empty: CYCLONEDDS_URI, else loopback
  double viewer_fps = 10.0;        ///< mesh frames to viewers per second
  double frame_rate = 0.0;         ///< physics frames per second; 0: the scene's frame_dt
  double client_timeout = 1.0;     ///< s without tool poses: the haptic client is gone
  std::string stats_json;          ///< write the exit statistics here too
};

class ServerApp {
 public:
  /// Returns -1 to continue, or an exit code (help, version, bad flags).
  int ParseArgs(int argc, char** argv);
  /// Runs what the flags ask; returns the process exit code.
  int Run();

 private:
  int RunHeadless();
  int RunRealtime();

  ServerOptions options_;
};

}  // namespace cutsim::server

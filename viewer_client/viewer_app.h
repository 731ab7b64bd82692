#pragma once
/// @file
/// The viewer application: command line, then a loop that polls the mesh
/// stream and renders at its own rate (independent of the physics rate).
/// Thin: the stream is common/transport/mesh_stream.h, drawing common/render.

#include <cstdint>
#include <optional>
#include <string>
#include <vector>

#include <Eigen/Core>

namespace cutsim::viewer {

struct ViewerOptions {
  std::string session = "default";
  uint32_t dds_domain = 0;
  std::string dds_config;     ///< File; empty = $CYCLONEDDS_URI, else the loopback config.
  std::string frames_dir;     ///< PNG frames, frame_000000.png, ...
  std::string video;          ///< .mp4/.mkv/... through ffmpeg.
  double fps = 10.0;          ///< Render rate, Hz.
  int width = 640;            ///< pixels
  int height = 480;           ///< pixels
  std::optional<Eigen::Vector3d> eye;     ///< m, world
  std::optional<Eigen::Vector3d> target;  ///< m, world
  bool stress = false;
  double force_full_scale = 1.0;  ///< N: the force that fills the gauge.
  std::optional<int64_t> max_frames;
  std::optional<double> duration;        ///< s of wall time
  std::optional<double> exit_when_idle;  ///< s without samples (after some arrived)
  std::string summary;                   ///< JSON file
  std::string frame_log;                 ///< one line per rendered frame: index seq hash sim_time mono_ns
  std::string log_level = "info";
  std::string serve;       ///< HOST:PORT of the browser observers' page; empty: none.
  std::string token_file;  ///< Observers' token (required off loopback).
  /// The instructor's token (--instructor-token-file): a page opened with
  /// `&instructor=<token>` steers a debrief; empty: every page is read-only.
  std::string instructor_token_file;
  std::vector<std::string> host_names;  ///< Further names browsers may open the page at (--host-name).
  std::string web_root;    ///< The page's files (web/observer).
  std::string lab;         ///< HOST:PORT of the lab page (every session on the domain); empty: none.
  std::string lab_root;    ///< The lab page's files (web/lab).
  std::string history;     ///< The lab's score history (SQLite): trainees' trends on the lab page; empty: none.
  std::string key_file;    ///< Session key: only frames signed with it are shown; empty: $CUTSIM_SESSION_KEY, else open.
};

/// The lab bridge's loop (`--lab`, lab_mode.cc): serves the lab page until
/// a signal or `--duration`; returns the exit code.
int RunLab(const ViewerOptions& options, const volatile int& stop);

class ViewerApp {
 public:
  /// Returns -1 to continue, or an exit code (help, bad flags).
  int ParseArgs(int argc, char** argv);
  /// Runs until a limit, idle timeout or signal; returns the exit code.
  int Run();

 private:
  ViewerOptions options_;
};

}  // namespace cutsim::viewer

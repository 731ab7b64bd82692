#pragma once
/// @file
/// Session recording and deterministic replay.
///
/// The real-time server (`--record FILE`) writes the session's *inputs* to an
/// LCM log (the format `lcm-logger` writes and `lcm-logplayer` reads; one
/// protobuf message per event, wire.proto):
///
///   CUTSIM_<session>_REC_HEADER  RecordHeader  scene, precision, threads, quantum
///   CUTSIM_<session>_REC_FRAME   RecordFrame   per physics frame: the frame time,
///                                              the tool pose applied before it (if
///                                              any), the topology version and cuts
///                                              after it, and the topology digest
///                                              whenever a cut changed it
///   CUTSIM_<session>_REC_END     RecordEnd     final mesh hash
///
/// Event timestamps are the server's CLOCK_REALTIME in µs, so `lcm-logplayer`
/// replays at the recorded pace. `cutsim-server --headless --replay FILE`
/// rebuilds the simulation from the header and feeds it the same frame times
/// and tool poses in the same order; it then checks every frame's cut
/// decisions (topology version and digest) and the final mesh hash against
/// the recording.
///
/// Determinism: replay is bit-for-bit the same computation as the recorded
/// session (same scene, precision and thread count; scenes under 20k tets run
/// one thread). The final hash is over positions quantised to `quantum`
/// (10 µm) plus the exact topology, so it is insensitive to sub-quantum
/// round-off. Builds differ in floating-point code: the portable builds
/// (presets dev, ci, asan: x86-64 SSE2, no FMA) produce identical results;
/// -march=native (release: FMA contraction, AVX packets) rounds differently
/// and may take a cut one frame earlier or later, which replay reports as a
/// mismatch. The header records which class of build made the recording and
/// replay warns when it differs.

#include <cstdint>
#include <filesystem>
#include <memory>
#include <optional>
#include <string>

#include "common/debrief/debrief_player.h"
#include "common/sim/simulation.h"
#include "common/transport/lcm_log.h"
#include "common/transport/mesh_stream.h"
#include "cutsim/v1/report.pb.h"
#include "cutsim/v1/wire.pb.h"

namespace cutsim::server {

/// Quantum of the recorded final mesh hash, m.
inline constexpr double kRecordQuantum = 1e-5;
/// Every this many frames a recording carries the state's hash
/// (RecordFrame.mesh_hash).
inline constexpr uint64_t kRecordHashEveryFrames = 20;

/// "portable" or "native-fma": the floating-point class of this build.
[[nodiscard]] const char* BuildClass();

/// Hash of the simulation's state: exact topology and positions (world and
/// rest) quantised to `quantum`. Allocates (fills a MeshView).
[[nodiscard]] uint64_t FinalMeshHash(const sim::Simulation& simulation, double quantum,
                                     sim::MeshView* scratch);

/// Writes a recording. Lives on the physics thread; `Frame` does one small
/// buffered write per frame (and a topology digest on frames that cut).
class SessionRecorder {
 public:
  /// Creates `path` and writes the header through to the kernel, so an
  /// unwritable path or a full device fails here, at start. Throws
  /// `InputError` naming the file.
  SessionRecorder(const std::filesystem::path& path, const std::string& session,
                  const std::string& scene_path, const sim::Simulation& simulation);

  /// Records one frame after `AdvanceFrame(frame_time)`; `applied` is the
  /// tool pose set before it (nullopt: none this frame). A failed write is
  /// logged once and ends the recording; `error()` then says why.
  void Frame(double frame_time, const std::optional<sim::ToolPose>& applied,
             const sim::Simulation& simulation);
  /// Writes the final mesh hash, then flushes, syncs and closes the file;
  /// returns the hash. Throws `InputError` naming the file if the recording
  /// failed at any point (it is then incomplete).
  uint64_t Finish(const sim::Simulation& simulation);

  [[nodiscard]] uint64_t frames() const { return frames_; }
  /// Why the recording failed; empty while every write succeeded.
  [[nodiscard]] const std::string& error() const { return error_; }

 private:
  void Write(const std::string& channel, const google::protobuf::MessageLite& msg);

  transport::LcmLogWriter log_;
  std::string frame_channel_;
  std::string end_channel_;
  v1::RecordFrame frame_msg_;  // reused
  std::string buffer_;         // reused
  sim::MeshView view_;         // reused for digests
  uint64_t frames_ = 0;
  uint64_t last_version_ = 0;
  std::string error_;
};

/// What a replay found.
struct ReplayResult {
  bool match = false;
  std::string mismatch;         ///< First difference, e.g. "frame 212: topology version 3, recorded 2".
  uint64_t frames = 0;
  uint64_t cut_frames = 0;      ///< Frames whose topology changed.
  uint64_t hashed_frames = 0;   ///< Frames whose recorded mesh hash the re-run matched.
  uint64_t topology_version = 0;
  uint64_t cuts = 0;
  uint64_t mesh_hash = 0;
  uint64_t recorded_mesh_hash = 0;
  std::string session;
  std::string scene;
  double sim_time = 0.0;
  sim::SessionMetrics metrics;  ///< the re-run's measures
  v1::SessionReport report;     ///< the re-run's session report (measures, score, series)
};

/// Replays `path` (see the file comment). `scene_override` (if not empty)
/// replaces the recorded scene path; otherwise the recorded path is used, or
/// failing that a file of the same name next to the recording. Throws
/// `InputError` naming the file for a missing or malformed recording.
[[nodiscard]] ReplayResult ReplayRecording(const std::filesystem::path& path,
                                           const std::string& scene_override);

/// A recording read whole, for a debrief (`--replay FILE --live`).
struct Recording {
  v1::RecordHeader header;
  std::filesystem::path scene;                ///< the scene replayed (see ReplayRecording)
  std::vector<debrief::PlayerFrame> frames;   ///< every frame, checked as a replay checks them
  std::optional<v1::RecordEnd> end;           ///< absent when the server did not finish it
  std::vector<uint64_t> mesh_hashes;          ///< #frames: the live state's hash after each, 0 = not recorded
};

/// Most frames a debrief reads (about 5.8 h at 200 frames/s).
inline constexpr size_t kMaxDebriefFrames = size_t{1} << 22;

/// Reads `path` whole (the scene as ReplayRecording finds it). Throws
/// `InputError` naming the file and event for a malformed recording, or one
/// of more than kMaxDebriefFrames frames.
[[nodiscard]] Recording ReadRecording(const std::filesystem::path& path, const std::string& scene_override);

/// The hash a recording compares: `simulation`'s state at the recording's
/// quantum (RecordFrame.mesh_hash, RecordEnd.mesh_hash).
[[nodiscard]] uint64_t RecordingHash(const Recording& recording, const sim::Simulation& simulation);

}  // namespace cutsim::server

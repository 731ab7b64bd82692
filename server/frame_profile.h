#pragma once
/// @file
/// Where the real-time server's frames spend their wall time: each stage of
/// the loop (the simulation's own stages from Simulation::LastFrameTimes,
/// the implicit step's phases inside its dynamics, and the server's
/// publishing around them), per session: the mean and largest time of each,
/// how many overrunning frames each stage led, and the slowest frames stage
/// by stage. Fixed storage: recording a frame never allocates.

#include <array>
#include <cstdint>

#include "common/sim/frame_times.h"
#include "cutsim/v1/report.pb.h"

namespace cutsim::server {

/// The server loop's stages outside the simulation, in the loop's order.
enum class ServerStage : uint8_t {
  kToolPose,    ///< the newest tool pose taken from the link
  kJournal,     ///< the frame's topology events handed to the journal
  kLocalModel,  ///< the haptic local model (its stiffness) built and sent
  kRecord,      ///< the recorder's frame
  kViewer,      ///< a mesh frame to viewers
  kStatus,      ///< the per-second session status
  kCheckpoint,  ///< a periodic checkpoint
};
inline constexpr int kNumServerStages = 7;

class FrameProfile {
 public:
  /// Entries: the server's stages, the simulation's, then the dynamics'
  /// phases ("dynamics.solve", …), which are part of "dynamics".
  static constexpr int kNumEntries = kNumServerStages + sim::kNumFrameStages + sim::kNumDynamicsPhases;
  /// The slowest frames kept with their split.
  static constexpr int kSlowest = 5;

  /// Starts a frame's stage clock (CLOCK_MONOTONIC ns).
  void BeginFrame(int64_t now_ns);
  /// Ends the server stage that ran since the last mark.
  void End(ServerStage stage, int64_t now_ns);
  /// Takes the simulation's split of the time since the last mark (the
  /// frame's AdvanceFrame) and moves the mark.
  void EndSimulation(const sim::FrameTimes& times, int64_t now_ns);
  /// Ends the frame: its number, simulated time, wall time (s) and whether
  /// it overran its deadline.
  void EndFrame(uint64_t frame, double sim_time, double seconds, bool overran);

  /// Adds `frame_stages` and `slowest_frames` to the session's statistics.
  void AddToStats(v1::ServerSessionStats& stats) const;

 private:
  using Split = std::array<double, kNumEntries>;  // s per entry
  struct SlowFrame {
    uint64_t frame = 0;
    double sim_time = 0;
    double seconds = -1;  // < 0: unused slot
    Split split{};
  };
  static const char* EntryName(int entry);
  /// The longest top-level entry of a frame (a server or simulation stage).
  static int Leader(const Split& split);

  int64_t mark_ns_ = 0;
  Split frame_{};  // the current frame's split
  Split sum_{};
  Split max_{};
  std::array<uint32_t, kNumEntries> led_{};  // overrunning frames each top-level entry led
  uint64_t frames_ = 0;
  std::array<SlowFrame, kSlowest> slowest_{};
};

}  // namespace cutsim::server

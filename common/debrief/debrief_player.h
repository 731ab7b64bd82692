#pragma once
/// @file
/// A recorded session played again, with seeking: the debrief's engine. No
/// transport and no clock: the caller feeds it the recording's frames (the
/// frame times and the tool poses the live session applied) and moves it
/// through recorded time; the server paces it to the wall clock and
/// publishes what it shows.
///
/// At construction a pre-pass re-simulates the whole recording once, as
/// fast as the machine goes. On the way it keeps a checkpoint every
/// `checkpoint_every` seconds of recorded time (the checkpoint body of
/// common/sim/checkpoint.h plus the Simulation::Memo taken with it, in
/// memory) and the course of the cut: the force on the blade, the
/// deviation of each scored cut step from the plan and the frames that cut
/// (the timeline). A seek then restores the checkpoint at or before the
/// target on a fresh Simulation and simulates the rest, so it costs at most
/// `checkpoint_every` seconds of simulation plus a restore; a seek a short
/// way forward just steps on. Restored with its memo, the simulation
/// continues exactly as the pre-pass did (explicit scenes), so any frame
/// looks the same however it was reached.

#include <cstddef>
#include <cstdint>
#include <functional>
#include <memory>
#include <optional>
#include <vector>

#include "common/sim/simulation.h"

namespace cutsim::v1 {
class CheckpointBody;
}  // namespace cutsim::v1

namespace cutsim::debrief {

/// One recorded frame: what the live session did before and in it.
struct PlayerFrame {
  double frame_time = 0.0;            ///< s, the physics frame
  std::optional<sim::ToolPose> tool;  ///< the pose applied before it (none: the pose stays)
  uint64_t topology_version = 0;      ///< after it, as recorded
};

struct PlayerOptions {
  /// Recorded seconds between the pre-pass's checkpoints: a seek simulates
  /// at most this much.
  double checkpoint_every = 0.25;
  /// Memory the checkpoints may take, bytes (each is estimated at eight
  /// times its body's positions and velocities); beyond it they space out.
  size_t checkpoint_bytes = size_t{1} << 30;
  /// Samples of the force in the timeline (each the largest |f| of its span).
  int timeline_samples = 600;
};

/// The whole recording's course, from the pre-pass.
struct Timeline {
  double duration = 0.0;              ///< s, recorded time of the last frame's end
  std::vector<double> force_t;        ///< s, each force sample's span start
  std::vector<double> force_n;        ///< N, the largest |f| on the blade in the span
  std::vector<double> cut_t;          ///< s, scored cut steps (with a planned incision)
  std::vector<double> cut_deviation;  ///< m, each one's deviation from the planned line
  double tolerance = 0.0;             ///< m, the plan's band (0 without a plan)
  /// s, the end of each frame whose topology changed: the cut steps one
  /// steps between.
  std::vector<double> step_t;
};

/// What one seek did.
struct SeekReport {
  bool restored = false;     ///< from a checkpoint (else it stepped on from the current frame)
  double restore_from = 0;   ///< s, the checkpoint's time when restored
  size_t frames_stepped = 0; ///< frames simulated to reach the target
  double restore_s = 0;      ///< wall time making the fresh simulation and restoring it, s
  double step_s = 0;         ///< wall time stepping to the target, s
};

/// Makes a fresh Simulation of the recorded scene (settled, at time 0).
using SimulationFactory = std::function<std::unique_ptr<sim::Simulation>()>;

/// Called after each frame of the pre-pass with the frame's index (0-based)
/// and the simulation after it; returns false to stop the pre-pass early
/// (the recording then ends there).
using PrepassObserver = std::function<bool(size_t frame, const sim::Simulation& simulation)>;

class DebriefPlayer {
 public:
  /// Runs the pre-pass over `frames` (see the file comment); afterwards the
  /// player stands at the end of the recording (simulation() is the
  /// pre-pass's final state) until Seek. Throws InputError for an empty
  /// recording or bad options (naming the field), and when the simulation
  /// stops (the recording's frame that failed).
  DebriefPlayer(SimulationFactory make, std::vector<PlayerFrame> frames, PlayerOptions options = {},
                const PrepassObserver& observer = nullptr);
  ~DebriefPlayer();
  DebriefPlayer(const DebriefPlayer&) = delete;
  DebriefPlayer& operator=(const DebriefPlayer&) = delete;

  [[nodiscard]] const Timeline& timeline() const { return timeline_; }
  [[nodiscard]] double duration() const { return timeline_.duration; }
  /// Recorded time of the state shown now: the end of the frames applied, s.
  [[nodiscard]] double position() const { return end_time_[frame_]; }
  /// Frames applied (0: the start).
  [[nodiscard]] size_t frame() const { return frame_; }
  [[nodiscard]] size_t frames() const { return frames_.size(); }
  [[nodiscard]] bool at_end() const { return frame_ == frames_.size(); }
  [[nodiscard]] const sim::Simulation& simulation() const { return *sim_; }
  /// Checkpoints held (the start counts as one).
  [[nodiscard]] size_t checkpoints() const;

  /// Applies the next frame; false at the end. Throws InputError when the
  /// simulation stops.
  bool StepFrame();
  /// Steps while the next frame ends at or before `t`, s; returns the
  /// frames stepped.
  size_t AdvanceTo(double t);
  /// Shows the recording at `t` (clamped to [0, duration]): the frames whose
  /// end is at or before it applied, from the nearest checkpoint.
  SeekReport Seek(double t);
  /// The start of the next cut step after the position (the end of its
  /// frame), or nullopt after the last.
  [[nodiscard]] std::optional<double> NextStep() const;
  /// The last cut step before the position, or nullopt before the first.
  [[nodiscard]] std::optional<double> PreviousStep() const;

 private:
  struct Checkpoint;
  void Prepass(const PrepassObserver& observer);
  void Apply(size_t index, sim::Simulation& simulation) const;
  [[nodiscard]] size_t FrameAt(double t) const;
  void BuildTimeline(const std::vector<double>& frame_force);
  /// Widens the period when the checkpoints would exceed their memory.
  void SpaceCheckpoints(const v1::CheckpointBody& first);

  SimulationFactory make_;
  std::vector<PlayerFrame> frames_;
  PlayerOptions options_;
  std::vector<double> end_time_;  // #frames + 1: recorded time after k frames
  std::vector<Checkpoint> checkpoints_;
  std::unique_ptr<sim::Simulation> sim_;
  size_t frame_ = 0;
  Timeline timeline_;
};

}  // namespace cutsim::debrief

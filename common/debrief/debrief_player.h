#pragma once
/// @file
/// A recorded session played again, with seeking: the debrief's engine. No
/// transport and no clock: the caller feeds it the recording's frames (the
/// frame times and the tool poses the live session applied) and moves it
/// through recorded time; the server paces it to the wall clock and
/// publishes what it shows.
///
/// At construction a producer thread starts re-simulating the whole
/// recording once on a simulation of its own, as fast as the machine goes,
/// while the player already stands at the start and plays: the picture
/// does not wait for it. On the way the producer keeps a checkpoint every
/// `checkpoint_every` seconds of recorded time (the checkpoint body of
/// common/sim/checkpoint.h plus the Simulation::Memo taken with it, in
/// memory) and the course of the cut: the force on the blade, the
/// deviation of each scored cut step from the plan and the frames that cut
/// (the timeline, growing as it goes). A seek restores the checkpoint at or
/// before the target on a fresh Simulation and simulates the rest, so once
/// the producer has passed the target it costs at most `checkpoint_every`
/// seconds of simulation plus a restore; a seek beyond what the producer has
/// reached simulates on from its latest checkpoint (or from the frame shown,
/// when that is nearer). Restored with its memo, the simulation continues
/// exactly as the producer did (explicit scenes), so any frame looks the
/// same however it was reached.

#include <atomic>
#include <condition_variable>
#include <cstddef>
#include <cstdint>
#include <deque>
#include <exception>
#include <functional>
#include <memory>
#include <mutex>
#include <optional>
#include <thread>
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

/// The recording's course, from the producer (complete once it finished).
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

/// Called on the producer's thread after each of its frames with the frame's
/// index (0-based) and the producer's simulation after it; returns false to
/// stop the producer (the frames after it stay playable, simulated when
/// reached, and NextStep does not see cut steps after it).
using PrepassObserver = std::function<bool(size_t frame, const sim::Simulation& simulation)>;

class DebriefPlayer {
 public:
  /// Starts the producer over `frames` (see the file comment) and stands at
  /// the start of the recording (frame 0, a fresh simulation). Throws
  /// InputError for an empty recording or bad options (naming the field).
  /// `make` and `observer` are called on the producer's thread while it
  /// runs (`make` on the caller's too): both must allow that.
  DebriefPlayer(SimulationFactory make, std::vector<PlayerFrame> frames, PlayerOptions options = {},
                PrepassObserver observer = nullptr);
  /// Stops the producer (after its current frame) and joins it.
  ~DebriefPlayer();
  DebriefPlayer(const DebriefPlayer&) = delete;
  DebriefPlayer& operator=(const DebriefPlayer&) = delete;

  /// The timeline as far as the producer has come (a copy).
  [[nodiscard]] Timeline timeline() const;
  [[nodiscard]] double duration() const { return end_time_.back(); }
  /// Recorded time of the state shown now: the end of the frames applied, s.
  [[nodiscard]] double position() const { return end_time_[frame_]; }
  /// Frames applied (0: the start).
  [[nodiscard]] size_t frame() const { return frame_; }
  [[nodiscard]] size_t frames() const { return frames_.size(); }
  [[nodiscard]] bool at_end() const { return frame_ == frames_.size(); }
  [[nodiscard]] const sim::Simulation& simulation() const { return *sim_; }
  /// Checkpoints held (the start counts as one).
  [[nodiscard]] size_t checkpoints() const;
  /// Frames the producer has simulated so far.
  [[nodiscard]] size_t produced() const { return produced_.load(); }
  /// True once the producer ended (the whole recording, a stop or a failure).
  [[nodiscard]] bool produced_all() const { return producer_done_.load(); }
  /// The producer's period between checkpoints (widened for memory), s.
  [[nodiscard]] double checkpoint_every() const;
  /// Blocks until the producer ended; throws the InputError it stopped on
  /// (the recording's frame where the simulation failed), if any.
  void WaitProduced();

  /// Applies the next frame; false at the end. Throws InputError when the
  /// simulation stops.
  bool StepFrame();
  /// Steps while the next frame ends at or before `t`, s; returns the
  /// frames stepped.
  size_t AdvanceTo(double t);
  /// Shows the recording at `t` (clamped to [0, duration]): the frames whose
  /// end is at or before it applied, from the nearest checkpoint produced so
  /// far or the frame shown, whichever is nearer.
  SeekReport Seek(double t);
  /// The start of the next cut step after the position (the end of its
  /// frame), or nullopt after the last the producer has seen.
  [[nodiscard]] std::optional<double> NextStep() const;
  /// The last cut step before the position, or nullopt before the first.
  [[nodiscard]] std::optional<double> PreviousStep() const;

 private:
  struct Checkpoint;
  /// The producer's thread body.
  void Produce(const PrepassObserver& observer);
  void Apply(size_t index, sim::Simulation& simulation) const;
  [[nodiscard]] size_t FrameAt(double t) const;
  /// The timeline from the forces of the first `produced` frames and the
  /// producer's simulation (its cut points); called on the producer's thread.
  [[nodiscard]] Timeline BuildTimeline(const std::vector<double>& frame_force, size_t produced,
                                       const sim::Simulation& producer) const;
  /// Widens the period when the checkpoints would exceed their memory.
  [[nodiscard]] double SpacedPeriod(const v1::CheckpointBody& first) const;

  SimulationFactory make_;
  const std::vector<PlayerFrame> frames_;
  PlayerOptions options_;
  std::vector<double> end_time_;  // #frames + 1: recorded time after k frames

  // Shared with the producer: under mu_ (checkpoints_ only grows; a deque
  // keeps the ones taken in place, and they do not change once taken).
  mutable std::mutex mu_;
  std::condition_variable done_cv_;
  std::deque<Checkpoint> checkpoints_;
  std::vector<double> step_t_;  // cut steps seen so far, s
  Timeline timeline_;
  double checkpoint_every_ = 0.0;
  std::exception_ptr failure_;  // what stopped the producer, if anything
  std::atomic<size_t> produced_{0};
  std::atomic<bool> producer_done_{false};
  std::atomic<bool> stop_{false};

  // The picture shown: the caller's thread only.
  std::unique_ptr<sim::Simulation> sim_;
  size_t frame_ = 0;

  std::thread producer_;  // last: starts after everything above exists
};

}  // namespace cutsim::debrief

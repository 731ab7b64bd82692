#pragma once
/// @file
/// A stage of the frame and the part of a checkpoint it owns. The engine's
/// checkpoint is the list of its stages' parts (the Engine's Stages() in
/// simulation.cc), so every stage states what survives a restart: it
/// implements Save, Check and Restore, and a stage without state of its
/// own says so in them.
///
/// A restore goes in two passes so that a bad file changes nothing: every
/// stage checks its part first (Check), and only then does every stage
/// apply its part (Restore), after the tissue's topology events are
/// replayed.

#include <cstdint>
#include <string>

namespace cutsim::v1 {
class CheckpointBody;
}  // namespace cutsim::v1

namespace cutsim::sim {

/// What a stage's Check reads besides the body: the file it came from and
/// the tissue as the body's events leave it.
struct PartCheck {
  const std::string& source;  ///< the checkpoint file, for errors
  int32_t num_nodes = 0;      ///< nodes after the body's events
};

class CheckpointedStage {
 public:
  virtual ~CheckpointedStage() = default;
  /// Writes the stage's state into its fields of `body`.
  virtual void Save(v1::CheckpointBody& body) const = 0;
  /// Checks the stage's fields of `body` (sizes, ranges, finite values);
  /// throws InputError naming `check.source` and the field. Changes nothing.
  virtual void Check(const v1::CheckpointBody& body, const PartCheck& check) const = 0;
  /// Applies the stage's checked fields of `body`; the tissue's events are
  /// replayed and the positions set before.
  virtual void Restore(const v1::CheckpointBody& body) = 0;
};

}  // namespace cutsim::sim

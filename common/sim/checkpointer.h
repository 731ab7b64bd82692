#pragma once
/// @file
/// What the server does with `--checkpoint FILE --checkpoint-every S
/// --resume`: the checkpoint (checkpoint.h) saved every S wall seconds and
/// at a clean exit, and beside it the event journal (event_journal.h), to
/// which every topology event is appended and fdatasync'd when it happens.
/// A checkpoint is the journal's compaction: once it is on disk the journal
/// starts anew after its last event. `--resume` restores the checkpoint,
/// then replays the journal's newer events, so a crash loses no cut; the
/// positions and velocities are the checkpoint's (up to S seconds old).
///
/// Which files belong together: every session started from the scene draws
/// a random lineage, written into its journal's header at start and into
/// each of its checkpoints; a resumed session keeps the lineage it resumed.
/// On resume:
/// - journal and checkpoint of one lineage: the checkpoint, then the
///   journal's events after the checkpoint's last (a journal that starts
///   after the checkpoint's last event is refused: events are missing);
/// - a journal of another lineage starting from the uncut scene: a session
///   started from the scene after that checkpoint was written, and killed
///   before its own first checkpoint; its journal replays on the uncut
///   scene and the older checkpoint is ignored (with a warning);
/// - only a checkpoint, or only a journal from the uncut scene: that one.

#include <cstdint>
#include <filesystem>
#include <optional>
#include <string>
#include <vector>

#include "common/sim/event_journal.h"
#include "common/sim/simulation.h"

namespace cutsim::sim {

class PeriodicCheckpointer {
 public:
  /// An empty `path` disables everything; `every` ≤ 0 saves only at exit.
  /// The journal is JournalPathFor(`path`); with `signer` (the session key,
  /// kept; may be null) its records are signed, and at resume only a journal
  /// signed with that key is read.
  PeriodicCheckpointer(std::filesystem::path path, double every, JournalSigner* signer = nullptr);

  [[nodiscard]] bool enabled() const { return !path_.empty(); }
  [[nodiscard]] const std::filesystem::path& journal_path() const { return journal_path_; }

  /// At start, on the freshly created `sim`: with `resume`, restores the
  /// checkpoint and replays the journal (see the file comment); then starts
  /// a new journal holding what the checkpoint on disk lacks. Returns
  /// whether anything was restored. Throws InputError for a corrupted or
  /// foreign checkpoint or journal, or a journal that cannot be written.
  bool Begin(Simulation& sim, bool resume);

  /// After each frame, right after the step: hands the frame's new
  /// topology events to the journal's writer thread (no disk access here).
  void JournalNewEvents(const Simulation& sim);

  /// Saves a checkpoint when the period has elapsed since the last save.
  void MaybeSave(const Simulation& sim);

  /// Saves now (clean exit); logs and returns false on failure. A saved
  /// checkpoint restarts the journal.
  bool Save(const Simulation& sim);

  /// Writes everything the journal holds queued (before reading counters
  /// at exit).
  void DrainJournal();

  [[nodiscard]] uint64_t saves() const { return saves_; }
  [[nodiscard]] uint64_t failures() const { return failures_; }
  /// The journal's counters (zero before Begin or when disabled).
  [[nodiscard]] JournalCounters journal_counters() const;

 private:
  /// Restores what the files hold into `sim`; sets `base_` and the journal
  /// payloads the new journal carries over.
  bool Resume(Simulation& sim);

  std::filesystem::path path_;
  JournalSigner* signer_ = nullptr;
  std::filesystem::path journal_path_;
  int64_t period_ns_ = 0;
  int64_t next_ns_ = 0;
  uint64_t saves_ = 0;
  uint64_t failures_ = 0;
  uint64_t lineage_ = 0;
  bool have_lineage_ = false;
  uint64_t base_ = 0;                  ///< last event version of the checkpoint on disk
  std::vector<std::string> carried_;   ///< journal records after `base_`, replayed at resume
  size_t journaled_ = 0;               ///< events of the simulation handed to the journal
  std::optional<EventJournal> journal_;
};

}  // namespace cutsim::sim

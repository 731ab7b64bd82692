#include "common/sim/checkpointer.h"

#include <cmath>
#include <random>
#include <utility>

#include <fmt/format.h>

#include "common/core/clock.h"
#include "common/core/error.h"
#include "common/core/log.h"
#include "common/sim/checkpoint.h"

namespace cutsim::sim {
namespace {

/// A random lineage, never 0 (0 is the lineage of checkpoints written
/// before lineages existed).
uint64_t NewLineage() {
  std::random_device rd;
  uint64_t v = 0;
  while (v == 0) v = (uint64_t{rd()} << 32) ^ uint64_t{rd()};
  return v;
}

/// The journal header of `sim`'s scene (identity only).
v1::JournalHeader IdentityHeader(const Simulation& sim) {
  const v1::CheckpointBody self = sim.CheckpointState();
  v1::JournalHeader h;
  h.set_scene_name(self.scene_name());
  h.set_scene_fingerprint(self.scene_fingerprint());
  h.set_precision(self.precision());
  return h;
}

/// Refuses a journal of another scene, mesh or precision than `self`'s.
void CheckJournalIdentity(const v1::JournalHeader& h, const v1::JournalHeader& self, const std::string& source) {
  if (h.scene_name() != self.scene_name()) {
    ThrowInputError({.file = source, .field = "scene_name"},
                    fmt::format("journal of scene '{}', this server runs '{}'", h.scene_name(), self.scene_name()));
  }
  if (h.scene_fingerprint() != self.scene_fingerprint()) {
    ThrowInputError({.file = source, .field = "scene_fingerprint"},
                    fmt::format("journal of another mesh or settings of scene '{}'", h.scene_name()));
  }
  if (h.precision() != self.precision()) {
    ThrowInputError({.file = source, .field = "precision"},
                    fmt::format("journal written in {} precision, this server runs {}", h.precision(),
                                self.precision()));
  }
}

}  // namespace

PeriodicCheckpointer::PeriodicCheckpointer(std::filesystem::path path, double every, JournalSigner* signer)
    : path_(std::move(path)),
      signer_(signer),
      journal_path_(path_.empty() ? std::filesystem::path() : JournalPathFor(path_)),
      period_ns_(every > 0 ? static_cast<int64_t>(std::llround(every * 1e9)) : 0),
      next_ns_(MonotonicNs() + period_ns_) {}

bool PeriodicCheckpointer::Begin(Simulation& sim, bool resume) {
  if (!enabled()) return false;
  v1::JournalHeader header = IdentityHeader(sim);
  const bool restored = resume && Resume(sim);
  if (!have_lineage_) {
    lineage_ = NewLineage();
    have_lineage_ = true;
  }
  header.set_lineage(lineage_);
  header.set_base_topology_version(base_);
  journal_.emplace(journal_path_, signer_);
  try {
    journal_->Start(header, carried_);
  } catch (...) {
    journal_.reset();
    throw;
  }
  Log().info("event journal {}: every cut is synced to it as it happens (after version {}, {} events carried over; "
             "{})",
             journal_path_.string(), base_, carried_.size(),
             signer_ != nullptr ? "records signed with the session key" : "no session key: records unsigned");
  carried_.clear();
  journaled_ = sim.TopologyEvents().size();
  return restored;
}

bool PeriodicCheckpointer::Resume(Simulation& sim) {
  const bool have_checkpoint = std::filesystem::exists(path_);
  const bool have_journal = std::filesystem::exists(journal_path_);
  if (!have_checkpoint && !have_journal) {
    Log().info("checkpoint {} does not exist yet: starting from the uncut scene", path_.string());
    return false;
  }
  std::optional<v1::CheckpointBody> body;
  if (have_checkpoint) body = ReadCheckpointFile(path_);
  std::optional<JournalContents> journal;
  const std::string jsource = journal_path_.string();
  bool use_checkpoint = body.has_value();
  if (have_journal) {
    journal = ReadJournalFile(journal_path_, signer_);
    CheckJournalIdentity(journal->header, IdentityHeader(sim), jsource);
    const v1::JournalHeader& h = journal->header;
    // Two sessions' files side by side: resuming either would lose the
    // other's cuts (and the next checkpoint would overwrite the first), so
    // the user chooses, by moving one away.
    if (body && h.lineage() != body->lineage()) {
      ThrowInputError({.file = jsource, .field = "lineage"},
                      fmt::format("journal of another session (lineage {:016x}, continuing version {}) than "
                                  "checkpoint {} (lineage {:016x}, {} events): the two do not belong together; "
                                  "move away the one whose session should not resume",
                                  h.lineage(), h.base_topology_version(), path_.string(), body->lineage(),
                                  body->events_size()));
    }
    if (!use_checkpoint && h.base_topology_version() != 0) {
      ThrowInputError({.file = jsource, .field = "base_topology_version"},
                      fmt::format("the journal continues a checkpoint at version {}, but {} does not exist",
                                  h.base_topology_version(), path_.string()));
    }
    if (use_checkpoint && h.base_topology_version() > LastEventVersion(*body)) {
      ThrowInputError({.file = jsource, .field = "base_topology_version"},
                      fmt::format("the journal continues version {}, but checkpoint {} holds events up to version "
                                  "{} only: the events between are missing (an older copy of the checkpoint?)",
                                  h.base_topology_version(), path_.string(), LastEventVersion(*body)));
    }
  }
  if (use_checkpoint) {
    sim.RestoreCheckpointState(*body, path_.string());
    base_ = LastEventVersion(*body);
    lineage_ = body->lineage();
    have_lineage_ = true;
  }
  size_t replayed = 0;
  if (journal) {
    if (!use_checkpoint) {
      lineage_ = journal->header.lineage();
      have_lineage_ = true;
    }
    std::vector<NamedEvent> named;
    uint64_t cuts = 0;
    for (const JournalEntry& e : journal->entries) {
      if (e.record.event().version() <= base_) continue;
      named.push_back({&e.record.event(), fmt::format("record at byte {}.event", e.offset)});
      cuts = e.record.cuts();
      carried_.push_back(e.payload);
    }
    sim.ApplyTopologyEvents(named, cuts, jsource);
    replayed = named.size();
  }
  const SimulationSummary s = sim.QuickSummary();
  if (use_checkpoint) {
    Log().info("resumed from checkpoint {}: t = {:.4g} s, {} cuts, topology version {} ({} events from journal {})",
               path_.string(), s.sim_time, s.cuts, s.topology_version, replayed, jsource);
  } else {
    Log().info("resumed from event journal {}: {} events on the uncut scene, {} cuts, topology version {}", jsource,
               replayed, s.cuts, s.topology_version);
  }
  if (replayed > 0) {
    Log().info("the journal restores the topology; positions and velocities are the checkpoint's (t = {:.4g} s)",
               s.sim_time);
  }
  return true;
}

void PeriodicCheckpointer::JournalNewEvents(const Simulation& sim) {
  if (!journal_) return;
  const std::span<const cutting::TopologyEvent> events = sim.TopologyEvents();
  if (journaled_ >= events.size()) return;
  const uint64_t cuts = sim.Tool().cuts;
  const double t = sim.sim_time();
  while (journaled_ < events.size()) journal_->Append(events[journaled_++], cuts, t);
}

void PeriodicCheckpointer::MaybeSave(const Simulation& sim) {
  if (!enabled() || period_ns_ <= 0) return;
  const int64_t now = MonotonicNs();
  if (now < next_ns_) return;
  next_ns_ = now + period_ns_;
  (void)Save(sim);
}

bool PeriodicCheckpointer::Save(const Simulation& sim) {
  if (!enabled()) return false;
  try {
    const v1::CheckpointBody body = SaveCheckpoint(sim, path_, lineage_);
    ++saves_;
    // The checkpoint holds every event so far: the journal starts anew
    // after its last one, once the records queued before are written.
    base_ = LastEventVersion(body);
    journaled_ = sim.TopologyEvents().size();
    if (journal_) journal_->Restart(base_);
    Log().debug("checkpoint {} written (t = {:.4g} s, topology version {})", path_.string(), sim.sim_time(),
                sim.topology_version());
    return true;
  } catch (const std::exception& e) {
    ++failures_;
    Log().error("checkpoint not written: {}", e.what());
    return false;
  }
}

void PeriodicCheckpointer::DrainJournal() {
  if (journal_) journal_->Drain();
}

JournalCounters PeriodicCheckpointer::journal_counters() const {
  return journal_ ? journal_->counters() : JournalCounters{};
}

}  // namespace cutsim::sim

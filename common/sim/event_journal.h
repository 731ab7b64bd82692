#pragma once
/// @file
/// The event journal beside a checkpoint (`<checkpoint>.journal`): every
/// topology event made durable when it happens, so a crash between two
/// checkpoints loses no cut. Append-only records, each framed as
///
///     u32 little-endian payload length | u64 little-endian FNV-1a 64 of the
///     payload | payload (protobuf)
///
/// The first record is a v1::JournalHeader (scene identity, the session's
/// lineage, the version of the last event of the checkpoint it continues);
/// every later one a v1::JournalRecord holding the checkpoint's own event
/// message (proto/cutsim/v1/checkpoint.proto).
///
/// Writing: `EventJournal` hands records to one writer thread through a
/// bounded queue; the thread writes each record and fdatasyncs it, so the
/// physics thread never waits for the disk. A new journal (at start and
/// after each checkpoint, its compaction) is written whole to a temporary
/// file, synced and renamed over the old one, then the directory is synced.
///
/// Reading: a record that runs past the end of the file, or a last record
/// whose checksum fails, or a zero-filled tail is a torn write: reading stops
/// there with a warning naming the file and byte offset and keeps the valid
/// prefix. A record with more bytes after it that fails its checksum, or any
/// checksummed record that does not parse, is corruption: refused with an
/// InputError naming the file and byte offset.
///
/// Authentication: with the session key (a JournalSigner, journal_signer.h)
/// the header says `authenticated` and the header and every record carry the
/// key's HMAC as a trailer, so an edited record whose checksum was
/// recomputed is still refused, naming the record. A signed journal is
/// refused without the key, and an unsigned one with a key (it could have
/// been written by anyone).

#include <atomic>
#include <condition_variable>
#include <cstddef>
#include <cstdint>
#include <deque>
#include <filesystem>
#include <mutex>
#include <span>
#include <string>
#include <thread>
#include <vector>

#include "common/cutting/topology_event.h"
#include "common/sim/journal_signer.h"
#include "cutsim/v1/checkpoint.pb.h"

namespace cutsim::sim {

/// Largest journal record, bytes (64 MiB): far above one cut step's event.
inline constexpr uint32_t kMaxJournalRecordBytes = uint32_t{64} << 20;
/// Bytes of a record's frame before its payload (length, checksum).
inline constexpr size_t kJournalFrameBytes = 12;
/// Records the writer thread's queue holds before the journal drops events
/// (and counts a failure) rather than block the physics thread.
inline constexpr size_t kJournalQueueCapacity = 256;

/// The journal file beside `checkpoint`.
[[nodiscard]] std::filesystem::path JournalPathFor(const std::filesystem::path& checkpoint);

/// `payload` framed as a journal record (length, checksum, payload).
[[nodiscard]] std::string FrameJournalRecord(const std::string& payload);

/// One event record read back, with the byte offset of its frame.
struct JournalEntry {
  uint64_t offset = 0;
  v1::JournalRecord record;
  std::string payload;  ///< the record's bytes as stored (carried into a new journal verbatim)
};

/// A journal read back: its header and the valid records in order.
struct JournalContents {
  v1::JournalHeader header;
  std::vector<JournalEntry> entries;
  uint64_t valid_bytes = 0;  ///< length of the valid prefix
  bool torn = false;         ///< a torn tail was left out (at byte `valid_bytes`)
};

/// Reads `path` (see the file comment for torn tails and corruption); logs a
/// warning for a torn tail. Throws InputError naming the file and the byte
/// offset for a bad header or a corrupt record, and with `signer` (the
/// session key) for a record whose tag is missing or does not match; without
/// one, for a signed journal.
[[nodiscard]] JournalContents ReadJournalFile(const std::filesystem::path& path, JournalSigner* signer = nullptr);

/// Journal counters (a snapshot; the writer thread updates them).
struct JournalCounters {
  uint64_t records = 0;          ///< event records written and synced
  uint64_t failures = 0;         ///< failed writes, syncs, restarts; records dropped
  uint64_t restarts = 0;         ///< new journals written
  uint64_t durable_version = 0;  ///< topology version of the newest synced record
  double sync_max_seconds = 0;   ///< hand-off → synced, largest
  double sync_mean_seconds = 0;  ///< hand-off → synced, mean
};

/// The journal's writer. Not copyable; one per journal file.
class EventJournal {
 public:
  /// With `signer` (kept; may be null) every record is signed with the
  /// session key.
  explicit EventJournal(std::filesystem::path path, JournalSigner* signer = nullptr);
  /// Writes everything queued, then stops the writer thread.
  ~EventJournal();
  EventJournal(const EventJournal&) = delete;
  EventJournal& operator=(const EventJournal&) = delete;

  [[nodiscard]] const std::filesystem::path& path() const { return path_; }

  /// Writes a new journal atomically on this thread (`header`, then the
  /// `carried` record payloads as they are), replacing any old one, opens it
  /// for appends and starts the writer thread. Throws InputError naming the
  /// file when it cannot be written: the server refuses to start.
  void Start(const v1::JournalHeader& header, std::span<const std::string> carried);

  /// Hands a copy of `event` to the writer thread, which serialises,
  /// writes and fdatasyncs it. Never waits for the disk: with the queue full
  /// the event is dropped, counted as a failure, and no later record is
  /// written until the next Restart (the journal keeps a gap-free prefix).
  void Append(const cutting::TopologyEvent& event, uint64_t cuts, double sim_time);

  /// After a checkpoint holding every event up to `base_version` is on
  /// disk: the writer thread starts a new journal (header with that base)
  /// once the records queued before are written. A restart that fails
  /// before its rename keeps the old journal (still valid) in use; one
  /// that fails after it writes no record until the next restart. Either
  /// is counted as a failure.
  void Restart(uint64_t base_version);

  /// Waits until everything queued so far is written (or has failed).
  void Drain();

  [[nodiscard]] JournalCounters counters() const;

 private:
  struct Item {
    enum class Kind { kRecord, kRestart, kStop } kind = Kind::kRecord;
    cutting::TopologyEvent event;
    uint64_t cuts = 0;
    double sim_time = 0;
    uint64_t base_version = 0;
    int64_t queued_ns = 0;
  };

  void Run();
  void WriteRecord(const Item& item);
  void DoRestart(uint64_t base_version);
  /// Writes header + carried records to path.tmp, syncs, renames, syncs the
  /// directory and opens the result for appends. Throws InputError.
  void WriteNewJournal(const v1::JournalHeader& header, std::span<const std::string> carried);
  /// Counts a failure; the first is logged as an error naming the file.
  void Fail(const std::string& what);

  const std::filesystem::path path_;
  JournalSigner* const signer_;  ///< used by one thread at a time: Start's, then the writer's
  v1::JournalHeader header_;
  // Writer thread only (and Start, before the thread runs).
  int fd_ = -1;
  uint64_t good_bytes_ = 0;  ///< the file's valid length
  bool broken_ = false;      ///< a record failed or was dropped: write none until a restart
  std::string frame_;        ///< reused serialisation buffer
  // Shared with the physics thread.
  mutable std::mutex mutex_;
  std::condition_variable wake_;
  std::condition_variable drained_;
  std::deque<Item> queue_;
  size_t records_queued_ = 0;  ///< kRecord items in queue_
  bool busy_ = false;          ///< the writer holds an item
  bool dropping_ = false;      ///< an event was dropped since the last restart was queued
  std::thread thread_;
  // Counters.
  std::atomic<uint64_t> records_{0};
  std::atomic<uint64_t> failures_{0};
  std::atomic<uint64_t> restarts_{0};
  std::atomic<uint64_t> durable_version_{0};
  std::atomic<int64_t> sync_max_ns_{0};
  std::atomic<int64_t> sync_total_ns_{0};
};

}  // namespace cutsim::sim

#include "common/sim/event_journal.h"

#include <fcntl.h>
#include <unistd.h>

#include <algorithm>
#include <cerrno>
#include <cstring>
#include <utility>

#include <fmt/format.h>

#include "common/core/clock.h"
#include "common/core/error.h"
#include "common/core/hash.h"
#include "common/core/input_file.h"
#include "common/core/log.h"
#include "common/sim/checkpoint.h"

namespace cutsim::sim {
namespace {

constexpr char kJournalMagic[] = "cutsim-journal";
constexpr uint32_t kJournalFormatVersion = 1;

void PutLe(uint64_t value, int bytes, std::string& out) {
  for (int i = 0; i < bytes; ++i) out.push_back(static_cast<char>((value >> (8 * i)) & 0xffu));
}

uint64_t GetLe(const std::string& in, size_t at, int bytes) {
  uint64_t v = 0;
  for (int i = 0; i < bytes; ++i) v |= uint64_t{static_cast<unsigned char>(in[at + static_cast<size_t>(i)])} << (8 * i);
  return v;
}

/// Writes all of `bytes` to `fd`; false with errno set on failure.
bool WriteAll(int fd, const char* bytes, size_t size) {
  size_t done = 0;
  while (done < size) {
    const ssize_t n = ::write(fd, bytes + done, size - done);
    if (n < 0 && errno == EINTR) continue;
    if (n <= 0) {
      if (n == 0) errno = EIO;
      return false;
    }
    done += static_cast<size_t>(n);
  }
  return true;
}

std::string ErrnoText() { return std::strerror(errno); }

/// fsync of `path`'s directory, so a rename into it is on disk.
bool SyncDirectoryOf(const std::filesystem::path& path) {
  std::filesystem::path dir = path.parent_path();
  if (dir.empty()) dir = ".";
  const int fd = ::open(dir.c_str(), O_RDONLY | O_DIRECTORY | O_CLOEXEC);
  if (fd < 0) return false;
  const bool ok = ::fsync(fd) == 0;
  const int err = errno;
  ::close(fd);
  errno = err;
  return ok;
}

bool AllZero(const std::string& bytes, size_t from) {
  return std::all_of(bytes.begin() + static_cast<std::ptrdiff_t>(from), bytes.end(), [](char c) { return c == 0; });
}

/// Bytes of checksummed payload a search for a record after a bad one may
/// hash: bounds the work a hostile file can ask for.
constexpr size_t kMaxTailScanBytes = size_t{64} << 20;

/// Whether a whole record (a length in range that fits, and a payload that
/// passes its checksum) starts anywhere in bytes[from, end). A tail that
/// holds none is what a torn write or stray bytes left, not a journal with
/// records past a corrupted one. A search that would hash more than
/// kMaxTailScanBytes answers yes: the file is then refused, never trusted.
bool HoldsAWholeRecord(const std::string& bytes, size_t from) {
  size_t hashed = 0;
  for (size_t p = from; p + kJournalFrameBytes <= bytes.size(); ++p) {
    const uint64_t length = GetLe(bytes, p, 4);
    if (length == 0 || length > kMaxJournalRecordBytes || length > bytes.size() - p - kJournalFrameBytes) continue;
    hashed += static_cast<size_t>(length);
    if (hashed > kMaxTailScanBytes) return true;
    if (Fnv1a64(bytes.data() + p + kJournalFrameBytes, static_cast<size_t>(length)) == GetLe(bytes, p + 4, 8)) {
      return true;
    }
  }
  return false;
}

}  // namespace

std::filesystem::path JournalPathFor(const std::filesystem::path& checkpoint) {
  return checkpoint.string() + ".journal";
}

std::string FrameJournalRecord(const std::string& payload) {
  std::string out;
  out.reserve(kJournalFrameBytes + payload.size());
  PutLe(payload.size(), 4, out);
  PutLe(Fnv1a64(payload.data(), payload.size()), 8, out);
  out += payload;
  return out;
}

// ---- reading ----------------------------------------------------------------

JournalContents ReadJournalFile(const std::filesystem::path& path, JournalSigner* signer) {
  const std::string source = path.string();
  const std::string bytes = ReadInputFile(source, "event journal", kMaxCheckpointBytes);
  JournalContents out;
  auto at = [](uint64_t offset) { return fmt::format("record at byte {}", offset); };
  size_t offset = 0;
  bool have_header = false;
  while (offset < bytes.size()) {
    const size_t left = bytes.size() - offset;
    // Past the end of the file, or the file's last record failing its
    // checksum, or zeros to the end: a write the crash tore. Only after the
    // header: the header is written whole and renamed into place.
    auto torn = [&](const std::string& why) {
      if (!have_header) ThrowInputError({.file = source, .field = at(offset)}, "journal header " + why);
      out.torn = true;
      Log().warn("event journal {}: torn record at byte {} ({}): keeping the {} records before it", source, offset,
                 why, out.entries.size());
    };
    if (left < kJournalFrameBytes) {
      torn(fmt::format("{} bytes, a record frame needs {}", left, kJournalFrameBytes));
      break;
    }
    const uint64_t length = GetLe(bytes, offset, 4);
    const uint64_t checksum = GetLe(bytes, offset + 4, 8);
    if (length == 0 || length > kMaxJournalRecordBytes) {
      if (have_header && AllZero(bytes, offset)) {
        torn("zeros to the end of the file");
        break;
      }
      if (have_header && !HoldsAWholeRecord(bytes, offset + 1)) {
        torn(fmt::format("{} bytes to the end of the file hold no whole record", left));
        break;
      }
      ThrowInputError({.file = source, .field = at(offset)},
                      fmt::format("record length {} outside 1..{} bytes: the journal is corrupted", length,
                                  kMaxJournalRecordBytes));
    }
    if (length > left - kJournalFrameBytes) {
      torn(fmt::format("{} payload bytes of {} present", left - kJournalFrameBytes, length));
      break;
    }
    const size_t end = offset + kJournalFrameBytes + static_cast<size_t>(length);
    std::string payload = bytes.substr(offset + kJournalFrameBytes, static_cast<size_t>(length));
    // With the key, only what it signed is read: the tag is checked on the
    // bytes as stored, before anything is parsed.
    size_t body_size = payload.size();
    if (signer != nullptr && Fnv1a64(payload.data(), payload.size()) == checksum) {
      switch (signer->Check(payload, &body_size)) {
        case JournalSigner::Verdict::kOk:
          break;
        case JournalSigner::Verdict::kUnsigned:
          ThrowInputError({.file = source, .field = at(offset)},
                          "not signed: the journal was written without the session key (or altered); with a key "
                          "only a journal signed with it is read");
        case JournalSigner::Verdict::kForged:
          ThrowInputError({.file = source, .field = at(offset)},
                          "its HMAC does not match the session key: the record was altered, or the journal was "
                          "written with another key");
      }
    }
    if (Fnv1a64(payload.data(), payload.size()) != checksum) {
      if (end == bytes.size() || AllZero(bytes, offset + kJournalFrameBytes)) {
        torn("the last record's checksum fails");
        break;
      }
      if (have_header && !HoldsAWholeRecord(bytes, offset + 1)) {
        torn(fmt::format("{} bytes to the end of the file hold no whole record", left));
        break;
      }
      ThrowInputError({.file = source, .field = at(offset)},
                      "checksum mismatch with records after it: the journal is corrupted");
    }
    if (!have_header) {
      if (!out.header.ParseFromArray(payload.data(), static_cast<int>(body_size)) ||
          out.header.magic() != kJournalMagic) {
        ThrowInputError({.file = source, .field = at(offset)}, "not a cutsim event journal (no journal header)");
      }
      if (out.header.format_version() != kJournalFormatVersion) {
        ThrowInputError({.file = source, .field = at(offset) + ".format_version"},
                        fmt::format("version {}, this build reads {}", out.header.format_version(),
                                    kJournalFormatVersion));
      }
      if (out.header.authenticated() && signer == nullptr) {
        ThrowInputError({.file = source, .field = at(offset)},
                        "the journal is signed with a session key: resume with the same key (--key-file or "
                        "$CUTSIM_SESSION_KEY)");
      }
      have_header = true;
    } else {
      JournalEntry entry{.offset = offset};
      if (!entry.record.ParseFromArray(payload.data(), static_cast<int>(body_size)) || !entry.record.has_event()) {
        ThrowInputError({.file = source, .field = at(offset)}, "the record does not parse as a journal record");
      }
      entry.payload = std::move(payload);
      out.entries.push_back(std::move(entry));
    }
    offset = end;
    out.valid_bytes = offset;
  }
  if (!have_header) ThrowInputError({.file = source}, "empty: not a cutsim event journal");
  return out;
}

// ---- writing ----------------------------------------------------------------

EventJournal::EventJournal(std::filesystem::path path, JournalSigner* signer)
    : path_(std::move(path)), signer_(signer) {}

EventJournal::~EventJournal() {
  if (thread_.joinable()) {
    {
      std::lock_guard lock(mutex_);
      queue_.push_back(Item{.kind = Item::Kind::kStop});
    }
    wake_.notify_one();
    thread_.join();
  }
  if (fd_ >= 0) ::close(fd_);
}

void EventJournal::Start(const v1::JournalHeader& header, std::span<const std::string> carried) {
  CUTSIM_CHECK(!thread_.joinable(), "EventJournal::Start called twice");
  header_ = header;
  header_.set_magic(kJournalMagic);
  header_.set_format_version(kJournalFormatVersion);
  header_.set_authenticated(signer_ != nullptr);
  WriteNewJournal(header_, carried);
  restarts_.fetch_add(1, std::memory_order_relaxed);
  thread_ = std::thread([this] { Run(); });
}

void EventJournal::Append(const cutting::TopologyEvent& event, uint64_t cuts, double sim_time) {
  {
    std::lock_guard lock(mutex_);
    if (dropping_ || records_queued_ >= kJournalQueueCapacity) {
      if (!dropping_) {
        Log().error("event journal {}: the writer is {} records behind (the disk is stalling): cuts are durable "
                    "only at the next checkpoint",
                    path_.string(), records_queued_);
      }
      dropping_ = true;
      failures_.fetch_add(1, std::memory_order_relaxed);
      return;
    }
    queue_.push_back(Item{.kind = Item::Kind::kRecord, .event = event, .cuts = cuts, .sim_time = sim_time,
                          .queued_ns = MonotonicNs()});
    ++records_queued_;
  }
  wake_.notify_one();
}

void EventJournal::Restart(uint64_t base_version) {
  {
    std::lock_guard lock(mutex_);
    queue_.push_back(Item{.kind = Item::Kind::kRestart, .base_version = base_version});
    dropping_ = false;  // records queued from now on follow the new journal's base
  }
  wake_.notify_one();
}

void EventJournal::Drain() {
  std::unique_lock lock(mutex_);
  drained_.wait(lock, [this] { return queue_.empty() && !busy_; });
}

JournalCounters EventJournal::counters() const {
  JournalCounters c;
  c.records = records_.load(std::memory_order_relaxed);
  c.failures = failures_.load(std::memory_order_relaxed);
  c.restarts = restarts_.load(std::memory_order_relaxed);
  c.durable_version = durable_version_.load(std::memory_order_relaxed);
  c.sync_max_seconds = 1e-9 * static_cast<double>(sync_max_ns_.load(std::memory_order_relaxed));
  if (c.records > 0) {
    c.sync_mean_seconds =
        1e-9 * static_cast<double>(sync_total_ns_.load(std::memory_order_relaxed)) / static_cast<double>(c.records);
  }
  return c;
}

void EventJournal::Run() {
  for (;;) {
    Item item;
    {
      std::unique_lock lock(mutex_);
      wake_.wait(lock, [this] { return !queue_.empty(); });
      item = std::move(queue_.front());
      queue_.pop_front();
      if (item.kind == Item::Kind::kRecord) --records_queued_;
      busy_ = true;
    }
    if (item.kind == Item::Kind::kRecord) WriteRecord(item);
    if (item.kind == Item::Kind::kRestart) DoRestart(item.base_version);
    {
      std::lock_guard lock(mutex_);
      busy_ = false;
      if (queue_.empty()) drained_.notify_all();
    }
    if (item.kind == Item::Kind::kStop) return;
  }
}

void EventJournal::Fail(const std::string& what) {
  if (failures_.fetch_add(1, std::memory_order_relaxed) == 0) {
    Log().error("event journal {}: {}: cuts from now on are durable only at the next checkpoint", path_.string(),
                what);
  } else {
    Log().debug("event journal {}: {}", path_.string(), what);
  }
}

void EventJournal::WriteRecord(const Item& item) {
  if (broken_ || fd_ < 0) {
    failures_.fetch_add(1, std::memory_order_relaxed);  // the first failure was logged
    return;
  }
  v1::JournalRecord record;
  *record.mutable_event() = EventToProto(item.event);
  record.set_cuts(item.cuts);
  record.set_sim_time(item.sim_time);
  std::string payload;
  if (!record.SerializeToString(&payload) || payload.size() > kMaxJournalRecordBytes) {
    broken_ = true;
    Fail(fmt::format("cannot serialise the event of version {} ({} bytes)", item.event.version, payload.size()));
    return;
  }
  frame_ = FrameJournalRecord(signer_ != nullptr ? signer_->Sign(std::move(payload)) : payload);
  const char* step = nullptr;
  if (!WriteAll(fd_, frame_.data(), frame_.size())) {
    step = "write";
  } else if (::fdatasync(fd_) != 0) {
    step = "fdatasync";
  }
  if (step != nullptr) {
    const std::string why = ErrnoText();
    // Cut back to the last whole record (best effort: a torn tail is read
    // as one anyway), and write no more records after the gap.
    (void)::ftruncate(fd_, static_cast<off_t>(good_bytes_));
    broken_ = true;
    Fail(fmt::format("{} of the record at byte {} (event version {}) failed: {}", step, good_bytes_,
                     item.event.version, why));
    return;
  }
  good_bytes_ += frame_.size();
  const int64_t took = MonotonicNs() - item.queued_ns;
  records_.fetch_add(1, std::memory_order_relaxed);
  durable_version_.store(item.event.version, std::memory_order_relaxed);
  sync_total_ns_.fetch_add(took, std::memory_order_relaxed);
  if (took > sync_max_ns_.load(std::memory_order_relaxed)) sync_max_ns_.store(took, std::memory_order_relaxed);
}

void EventJournal::DoRestart(uint64_t base_version) {
  v1::JournalHeader header = header_;
  header.set_base_topology_version(base_version);
  try {
    WriteNewJournal(header, {});
    header_ = header;
    restarts_.fetch_add(1, std::memory_order_relaxed);
  } catch (const InputError& e) {
    // Failed before the rename, the old journal stays: it continues an
    // older checkpoint of the same session and its records are still valid.
    // Failed after it, no record is written until the next restart.
    Fail(fmt::format("cannot start the new journal: {}", e.what()));
  }
}

void EventJournal::WriteNewJournal(const v1::JournalHeader& header, std::span<const std::string> carried) {
  std::string head;
  if (!header.SerializeToString(&head)) ThrowFileError(path_.string(), "cannot serialise the journal header");
  std::string bytes = FrameJournalRecord(signer_ != nullptr ? signer_->Sign(std::move(head)) : head);
  for (const std::string& payload : carried) bytes += FrameJournalRecord(payload);

  CheckOutputPath(path_.string(), "event journal");  // the rename below would replace a device or a pipe
  const std::string tmp = path_.string() + ".tmp";
  const int fd = ::open(tmp.c_str(), O_WRONLY | O_CREAT | O_TRUNC | O_CLOEXEC, 0644);
  if (fd < 0) ThrowFileError(tmp, fmt::format("cannot create the event journal: {}", ErrnoText()));
  const bool written = WriteAll(fd, bytes.data(), bytes.size());
  const char* failed = !written ? "write" : ::fsync(fd) != 0 ? "fsync" : nullptr;
  const std::string why = failed ? ErrnoText() : std::string();
  ::close(fd);
  if (failed) {
    (void)::unlink(tmp.c_str());
    ThrowFileError(tmp, fmt::format("event journal {} failed: {}", failed, why));
  }
  if (::rename(tmp.c_str(), path_.c_str()) != 0) {
    const std::string err = ErrnoText();
    (void)::unlink(tmp.c_str());
    ThrowFileError(path_.string(), fmt::format("cannot rename {} onto it: {}", tmp, err));
  }
  // The old file is gone from the path: nothing more goes to it, and
  // nothing goes to the new one until it is synced and open.
  if (fd_ >= 0) ::close(fd_);
  fd_ = -1;
  broken_ = true;
  if (!SyncDirectoryOf(path_)) {
    ThrowFileError(path_.string(), fmt::format("cannot sync its directory: {}", ErrnoText()));
  }
  const int append = ::open(path_.c_str(), O_WRONLY | O_APPEND | O_CLOEXEC);
  if (append < 0) ThrowFileError(path_.string(), fmt::format("cannot open the event journal: {}", ErrnoText()));
  fd_ = append;
  good_bytes_ = bytes.size();
  broken_ = false;
}

}  // namespace cutsim::sim

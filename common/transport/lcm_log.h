#pragma once
/// @file
/// LCM event logs, the `.lcm` files that `lcm-logger` writes (and the
/// server's recorder), for replaying a recorded tool stream and for writing
/// logs in tests. Each event has a channel, the raw payload and a timestamp
/// in microseconds (`lcm-logger` uses the UNIX epoch; only differences
/// between events matter for replay).
///
/// The format is read and written here rather than through liblcm's
/// `lcm_eventlog_*`, which trusts the lengths in each event header: every
/// event is 28 header bytes (sync word 0xEDA1DA01, event number, timestamp,
/// channel length, data length; big-endian), then the channel and the data.
/// The reader checks each length against kMaxLcmChannelBytes /
/// kMaxLcmEventBytes and against the bytes left in the file before reading.

#include <cstdint>
#include <cstdio>
#include <filesystem>
#include <optional>
#include <span>
#include <string>
#include <string_view>
#include <vector>

namespace cutsim::transport {

/// Longest channel name in a log event, bytes.
inline constexpr int64_t kMaxLcmChannelBytes = 1024;
/// Largest payload of a log event, bytes (16 MiB; cutsim's are < 1 MiB).
inline constexpr int64_t kMaxLcmEventBytes = int64_t{16} << 20;

/// One event of a log.
struct LcmLogEvent {
  int64_t eventnum = 0;
  int64_t timestamp_us = 0;  ///< µs (lcm-logger: since the UNIX epoch).
  std::string channel;
  std::vector<uint8_t> data;
};

/// Reads a log sequentially. Not thread-safe.
class LcmLogReader {
 public:
  /// Opens `path` (a regular file) for reading; throws `InputError` naming
  /// the file if it cannot be opened.
  explicit LcmLogReader(const std::filesystem::path& path);
  ~LcmLogReader();
  LcmLogReader(const LcmLogReader&) = delete;
  LcmLogReader& operator=(const LcmLogReader&) = delete;

  /// The next event, or nullopt at the end of the log or at a truncated last
  /// event (as a crashed writer leaves; logged). Bytes that are not a sync
  /// word are skipped to the next one, as liblcm does. A length over the
  /// limits above, or negative, throws `InputError` naming the file, the
  /// event's byte offset and the length.
  std::optional<LcmLogEvent> Next();

 private:
  std::string path_;
  std::FILE* file_ = nullptr;
  uint64_t size_ = 0;    // bytes in the file when opened
  uint64_t offset_ = 0;  // bytes consumed
};

/// Writes a log. Not thread-safe. Every write is checked: `Write`, `Flush`
/// and `Close` throw `InputError` naming the file (a full disk, an I/O error).
class LcmLogWriter {
 public:
  /// Creates (truncates) `path`; throws `InputError` naming the file on failure.
  explicit LcmLogWriter(const std::filesystem::path& path);
  /// Closes the file if `Close` was not called (errors are then only logged).
  ~LcmLogWriter();
  LcmLogWriter(const LcmLogWriter&) = delete;
  LcmLogWriter& operator=(const LcmLogWriter&) = delete;

  /// Appends one event (buffered).
  void Write(std::string_view channel, std::span<const uint8_t> data, int64_t timestamp_us);
  /// Hands the buffered events to the kernel.
  void Flush();
  /// Flushes, syncs to disk and closes; later calls do nothing.
  void Close();

 private:
  std::string path_;
  std::FILE* file_ = nullptr;
  int64_t next_eventnum_ = 0;
};

}  // namespace cutsim::transport

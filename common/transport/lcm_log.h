#pragma once
/// @file
/// RAII over LCM's event-log C API (`lcm_eventlog_*`): the `.lcm` files that
/// `lcm-logger` writes (and the server's recorder), for replaying a recorded
/// tool stream and for writing logs in tests. Each event has a channel, the
/// raw payload and a timestamp in microseconds (`lcm-logger` uses the UNIX
/// epoch; only differences between events matter for replay).

#include <cstdint>
#include <filesystem>
#include <optional>
#include <span>
#include <string>
#include <string_view>
#include <vector>

namespace cutsim::transport {

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
  /// Opens `path` for reading; throws `InputError` naming the file if it
  /// cannot be opened.
  explicit LcmLogReader(const std::filesystem::path& path);
  ~LcmLogReader();
  LcmLogReader(const LcmLogReader&) = delete;
  LcmLogReader& operator=(const LcmLogReader&) = delete;

  /// The next event, or nullopt at the end of the log (or at a truncated or
  /// corrupt tail: LCM resynchronises on the next sync word or stops).
  std::optional<LcmLogEvent> Next();

 private:
  std::string path_;
  void* log_ = nullptr;  // lcm_eventlog_t*
};

/// Writes a log. Not thread-safe.
class LcmLogWriter {
 public:
  /// Creates (truncates) `path`; throws `InputError` naming the file on failure.
  explicit LcmLogWriter(const std::filesystem::path& path);
  ~LcmLogWriter();
  LcmLogWriter(const LcmLogWriter&) = delete;
  LcmLogWriter& operator=(const LcmLogWriter&) = delete;

  /// Appends one event; throws `InputError` naming the file if writing fails.
  void Write(std::string_view channel, std::span<const uint8_t> data, int64_t timestamp_us);

 private:
  std::string path_;
  void* log_ = nullptr;  // lcm_eventlog_t*
  int64_t next_eventnum_ = 0;
};

}  // namespace cutsim::transport

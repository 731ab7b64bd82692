#include "common/transport/lcm_log.h"

#include <lcm/eventlog.h>

#include <string>

#include "common/core/error.h"

namespace cutsim::transport {
namespace {
lcm_eventlog_t* AsLog(void* p) { return static_cast<lcm_eventlog_t*>(p); }
}  // namespace

LcmLogReader::LcmLogReader(const std::filesystem::path& path) : path_(path.string()) {
  if (!std::filesystem::is_regular_file(path)) ThrowFileError(path_, "LCM log not found (or not a file)");
  log_ = lcm_eventlog_create(path_.c_str(), "r");
  if (log_ == nullptr) ThrowFileError(path_, "cannot open the LCM log for reading");
}

LcmLogReader::~LcmLogReader() {
  if (log_ != nullptr) lcm_eventlog_destroy(AsLog(log_));
}

std::optional<LcmLogEvent> LcmLogReader::Next() {
  lcm_eventlog_event_t* e = lcm_eventlog_read_next_event(AsLog(log_));
  if (e == nullptr) return std::nullopt;
  LcmLogEvent event;
  event.eventnum = e->eventnum;
  event.timestamp_us = e->timestamp;
  if (e->channellen > 0) event.channel.assign(e->channel, static_cast<size_t>(e->channellen));
  if (e->datalen > 0) {
    const auto* bytes = static_cast<const uint8_t*>(e->data);
    event.data.assign(bytes, bytes + e->datalen);
  }
  lcm_eventlog_free_event(e);
  return event;
}

LcmLogWriter::LcmLogWriter(const std::filesystem::path& path) : path_(path.string()) {
  log_ = lcm_eventlog_create(path_.c_str(), "w");
  if (log_ == nullptr) ThrowFileError(path_, "cannot create the LCM log");
}

LcmLogWriter::~LcmLogWriter() {
  if (log_ != nullptr) lcm_eventlog_destroy(AsLog(log_));
}

void LcmLogWriter::Write(std::string_view channel, std::span<const uint8_t> data, int64_t timestamp_us) {
  std::string name(channel);
  lcm_eventlog_event_t e{};
  e.eventnum = next_eventnum_++;
  e.timestamp = timestamp_us;
  e.channellen = static_cast<int32_t>(name.size());
  e.datalen = static_cast<int32_t>(data.size());
  e.channel = name.data();
  // LCM's API is not const-correct; it only reads the payload.
  e.data = const_cast<uint8_t*>(data.data());  // NOLINT(cppcoreguidelines-pro-type-const-cast)
  if (lcm_eventlog_write_event(AsLog(log_), &e) != 0) ThrowFileError(path_, "cannot write to the LCM log");
}

}  // namespace cutsim::transport

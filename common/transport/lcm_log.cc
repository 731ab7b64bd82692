#include "common/transport/lcm_log.h"

#include <unistd.h>

#include <array>
#include <cerrno>
#include <cstring>
#include <new>
#include <utility>

#include <fmt/format.h>

#include "common/core/error.h"
#include "common/core/input_file.h"
#include "common/core/log.h"

namespace cutsim::transport {
namespace {

constexpr uint32_t kSync = 0xEDA1DA01;
constexpr size_t kHeaderBytes = 4 + 8 + 8 + 4 + 4;

uint64_t LoadBigEndian(const uint8_t* p, int bytes) {
  uint64_t v = 0;
  for (int i = 0; i < bytes; ++i) v = (v << 8) | p[i];
  return v;
}

void StoreBigEndian(uint64_t v, int bytes, std::string& out) {
  for (int i = bytes - 1; i >= 0; --i) out.push_back(static_cast<char>((v >> (8 * i)) & 0xff));
}

}  // namespace

LcmLogReader::LcmLogReader(const std::filesystem::path& path) : path_(path.string()) {
  size_ = CheckInputFile(path_, "LCM log", UINT64_MAX);
  file_ = std::fopen(path_.c_str(), "rb");
  if (file_ == nullptr) ThrowFileError(path_, fmt::format("cannot open the LCM log: {}", std::strerror(errno)));
}

LcmLogReader::~LcmLogReader() {
  if (file_ != nullptr) std::fclose(file_);
}

std::optional<LcmLogEvent> LcmLogReader::Next() {
  std::array<uint8_t, kHeaderBytes> h{};
  // Find the next sync word (bytes between events are skipped, as liblcm does).
  uint32_t window = 0;
  int have = 0;
  uint64_t skipped = 0;
  while (true) {
    const int c = std::fgetc(file_);
    if (c == EOF) {
      if (have > 0 || skipped > 0) Log().warn("{}: {} trailing bytes after the last event", path_, skipped + have);
      return std::nullopt;
    }
    ++offset_;
    window = (window << 8) | static_cast<uint8_t>(c);
    if (have < 4) ++have;
    if (have == 4 && window == kSync) break;
    if (have == 4) ++skipped;
  }
  if (skipped > 0) Log().warn("{}: skipped {} bytes that are not an event before byte {}", path_, skipped, offset_ - 4);
  const uint64_t event_offset = offset_ - 4;
  const size_t got = std::fread(h.data() + 4, 1, kHeaderBytes - 4, file_);
  offset_ += got;
  if (got != kHeaderBytes - 4) {
    Log().warn("{}: the last event (byte {}) is truncated", path_, event_offset);
    return std::nullopt;
  }
  LcmLogEvent e;
  e.eventnum = static_cast<int64_t>(LoadBigEndian(h.data() + 4, 8));
  e.timestamp_us = static_cast<int64_t>(LoadBigEndian(h.data() + 12, 8));
  const auto channel_len = static_cast<int32_t>(LoadBigEndian(h.data() + 20, 4));
  const auto data_len = static_cast<int32_t>(LoadBigEndian(h.data() + 24, 4));
  const SourceRef where{.file = path_, .field = fmt::format("event {} (byte {})", e.eventnum, event_offset)};
  if (channel_len <= 0 || channel_len > kMaxLcmChannelBytes) {
    ThrowInputError(where, fmt::format("channel length {} is outside [1, {}]", channel_len, kMaxLcmChannelBytes));
  }
  if (data_len < 0 || data_len > kMaxLcmEventBytes) {
    ThrowInputError(where, fmt::format("data length {} is outside [0, {}]", data_len, kMaxLcmEventBytes));
  }
  const uint64_t need = static_cast<uint64_t>(channel_len) + static_cast<uint64_t>(data_len);
  if (offset_ + need > size_) {
    Log().warn("{}: the last event (byte {}) claims {} bytes, {} are left: truncated", path_, event_offset, need,
               size_ - offset_);
    return std::nullopt;
  }
  e.channel.resize(static_cast<size_t>(channel_len));
  e.data.resize(static_cast<size_t>(data_len));
  if (std::fread(e.channel.data(), 1, e.channel.size(), file_) != e.channel.size() ||
      std::fread(e.data.data(), 1, e.data.size(), file_) != e.data.size()) {
    ThrowInputError(where, "read error (the file changed while being read?)");
  }
  offset_ += need;
  return e;
}

LcmLogWriter::LcmLogWriter(const std::filesystem::path& path) : path_(path.string()) {
  file_ = std::fopen(path_.c_str(), "wb");
  if (file_ == nullptr) ThrowFileError(path_, fmt::format("cannot create the LCM log: {}", std::strerror(errno)));
}

LcmLogWriter::~LcmLogWriter() {
  if (file_ == nullptr) return;
  try {
    Close();
  } catch (const std::exception& e) {
    Log().error("{}", e.what());
  }
}

void LcmLogWriter::Write(std::string_view channel, std::span<const uint8_t> data, int64_t timestamp_us) {
  if (file_ == nullptr) ThrowFileError(path_, "the LCM log is closed");
  if (channel.empty() || static_cast<int64_t>(channel.size()) > kMaxLcmChannelBytes ||
      static_cast<int64_t>(data.size()) > kMaxLcmEventBytes) {
    ThrowFileError(path_, fmt::format("event on '{}' of {} bytes exceeds the log limits", channel, data.size()));
  }
  std::string header;
  header.reserve(kHeaderBytes);
  StoreBigEndian(kSync, 4, header);
  StoreBigEndian(static_cast<uint64_t>(next_eventnum_++), 8, header);
  StoreBigEndian(static_cast<uint64_t>(timestamp_us), 8, header);
  StoreBigEndian(channel.size(), 4, header);
  StoreBigEndian(data.size(), 4, header);
  if (std::fwrite(header.data(), 1, header.size(), file_) != header.size() ||
      std::fwrite(channel.data(), 1, channel.size(), file_) != channel.size() ||
      std::fwrite(data.data(), 1, data.size(), file_) != data.size()) {
    ThrowFileError(path_, fmt::format("cannot write to the LCM log: {}", std::strerror(errno)));
  }
}

void LcmLogWriter::Flush() {
  if (file_ == nullptr) return;
  if (std::fflush(file_) != 0) {
    ThrowFileError(path_, fmt::format("cannot write to the LCM log: {}", std::strerror(errno)));
  }
}

void LcmLogWriter::Close() {
  if (file_ == nullptr) return;
  std::FILE* f = std::exchange(file_, nullptr);
  // A write that failed earlier leaves the stream's error flag set even
  // when the flush itself has nothing left to do.
  const bool flushed = std::fflush(f) == 0 && std::ferror(f) == 0;
  int err = flushed ? 0 : (errno != 0 ? errno : EIO);
  // fsync fails with EINVAL on devices and pipes, which have no disk to sync.
  if (flushed && ::fsync(::fileno(f)) != 0 && errno != EINVAL) err = errno;
  if (std::fclose(f) != 0 && err == 0) err = errno;
  if (err != 0) ThrowFileError(path_, fmt::format("cannot finish the LCM log: {}", std::strerror(err)));
}

}  // namespace cutsim::transport

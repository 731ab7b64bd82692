#include "common/transport/stream_auth.h"

#include <sys/stat.h>

#include <algorithm>
#include <cctype>
#include <cstdlib>
#include <ctime>
#include <stdexcept>

#include <openssl/core_names.h>
#include <openssl/crypto.h>
#include <openssl/evp.h>
#include <openssl/params.h>

#include "common/core/error.h"
#include "common/core/input_file.h"
#include "common/core/log.h"

namespace cutsim::transport {
namespace {

int HexValue(char c) {
  if (c >= '0' && c <= '9') return c - '0';
  if (c >= 'a' && c <= 'f') return c - 'a' + 10;
  if (c >= 'A' && c <= 'F') return c - 'A' + 10;
  return -1;
}

EVP_MAC_CTX* Ctx(void* p) { return static_cast<EVP_MAC_CTX*>(p); }

// Protobuf key of `bytes hmac = 127` (wire type 2) as a two-byte varint, and
// the tag's length.
constexpr uint32_t kTrailerKey = (kTrailerField << 3) | 2;
constexpr uint8_t kTrailerKey0 = static_cast<uint8_t>((kTrailerKey & 0x7f) | 0x80);
constexpr uint8_t kTrailerKey1 = static_cast<uint8_t>(kTrailerKey >> 7);
static_assert(kTrailerKey >> 14 == 0, "the trailer's key is two varint bytes");
constexpr uint8_t kTrailerLength = HmacSha256::kTagBytes;

std::span<const uint8_t> AsBytes(std::string_view s) {
  return {reinterpret_cast<const uint8_t*>(s.data()), s.size()};
}

}  // namespace

int64_t RealtimeNowNs() noexcept {
  timespec ts{};
  clock_gettime(CLOCK_REALTIME, &ts);
  return static_cast<int64_t>(ts.tv_sec) * 1'000'000'000 + ts.tv_nsec;
}

SessionKey ParseSessionKey(std::string_view text, std::string_view source) {
  SessionKey key;
  int high = -1;
  size_t digits = 0;
  for (const char c : text) {
    if (std::isspace(static_cast<unsigned char>(c))) continue;
    const int v = HexValue(c);
    if (v < 0) {
      ThrowInputError({.file = std::string(source)},
                      "session key: not a hex digit (expected 32 to 128 hex digits, e.g. from "
                      "`openssl rand -hex 32`)");
    }
    ++digits;
    if (high < 0) {
      high = v;
      continue;
    }
    if (key.size == SessionKey::kMaxBytes) {
      ThrowInputError({.file = std::string(source)}, "session key: longer than 64 bytes (128 hex digits)");
    }
    key.bytes[key.size++] = static_cast<uint8_t>(high << 4 | v);
    high = -1;
  }
  if (high >= 0) {
    ThrowInputError({.file = std::string(source)},
                    "session key: odd number of hex digits (" + std::to_string(digits) + ")");
  }
  if (key.size < SessionKey::kMinBytes) {
    ThrowInputError({.file = std::string(source)},
                    "session key: " + std::to_string(key.size) +
                        " bytes; at least 16 needed (32 hex digits; `openssl rand -hex 32`)");
  }
  return key;
}

std::optional<SessionKey> LoadSessionKey(const std::string& key_file) {
  if (!key_file.empty()) {
    // A key is 64 hex digits: 4 KiB is generous, and /dev/zero is refused.
    const std::string text = ReadInputFile(key_file, "session key file", 4096);
    struct stat st{};
    if (::stat(key_file.c_str(), &st) == 0 && (st.st_mode & (S_IRWXG | S_IRWXO)) != 0) {
      Log().warn("{}: the session key file is accessible to group or others (chmod 600 it)",
                 key_file);
    }
    return ParseSessionKey(text, key_file);
  }
  if (const char* env = std::getenv(kSessionKeyEnv); env != nullptr && *env != '\0') {
    return ParseSessionKey(env, std::string("$") + kSessionKeyEnv);
  }
  return std::nullopt;
}

const char* ToString(AuthVerdict verdict) {
  switch (verdict) {
    case AuthVerdict::kOk:
      return "ok";
    case AuthVerdict::kNewEpoch:
      return "new-epoch";
    case AuthVerdict::kUnsigned:
      return "unsigned";
    case AuthVerdict::kForged:
      return "forged";
    case AuthVerdict::kReplayed:
      return "replayed";
    case AuthVerdict::kOutsideWindow:
      return "outside-window";
    case AuthVerdict::kInvalidEpoch:
      return "invalid-epoch";
    case AuthVerdict::kOtherSender:
      return "other-sender";
  }
  return "?";
}

// ---- HmacSha256 ------------------------------------------------------------------

HmacSha256::HmacSha256(const SessionKey& key) {
  EVP_MAC* mac = EVP_MAC_fetch(nullptr, "HMAC", nullptr);
  if (mac == nullptr) throw std::runtime_error("OpenSSL: HMAC is not available");
  EVP_MAC_CTX* ctx = EVP_MAC_CTX_new(mac);
  if (ctx == nullptr) {
    EVP_MAC_free(mac);
    throw std::runtime_error("OpenSSL: cannot create an HMAC context");
  }
  char digest[] = "SHA256";
  const OSSL_PARAM params[] = {
      OSSL_PARAM_construct_utf8_string(OSSL_MAC_PARAM_DIGEST, digest, 0),
      OSSL_PARAM_construct_end()};
  if (key.size < SessionKey::kMinBytes || EVP_MAC_init(ctx, key.bytes.data(), key.size, params) != 1) {
    EVP_MAC_CTX_free(ctx);
    EVP_MAC_free(mac);
    throw std::runtime_error("OpenSSL: cannot key HMAC-SHA256");
  }
  mac_ = mac;
  ctx_ = ctx;
}

HmacSha256::~HmacSha256() {
  EVP_MAC_CTX_free(Ctx(ctx_));
  EVP_MAC_free(static_cast<EVP_MAC*>(mac_));
}

bool HmacSha256::Begin() noexcept {
  // Re-initialise with the key set at construction (no key schedule again).
  return EVP_MAC_init(Ctx(ctx_), nullptr, 0, nullptr) == 1;
}

bool HmacSha256::Update(std::span<const uint8_t> bytes) noexcept {
  return bytes.empty() || EVP_MAC_update(Ctx(ctx_), bytes.data(), bytes.size()) == 1;
}

bool HmacSha256::Final(Tag* tag) noexcept {
  size_t out = 0;
  return EVP_MAC_final(Ctx(ctx_), tag->data(), &out, tag->size()) == 1 && out == kTagBytes;
}

// ---- Trailer and payload tags ----------------------------------------------------

SignedBytes SplitTrailer(std::span<const uint8_t> bytes) noexcept {
  if (bytes.size() < kTrailerBytes) return {bytes, {}};
  const size_t at = bytes.size() - kTrailerBytes;
  if (bytes[at] != kTrailerKey0 || bytes[at + 1] != kTrailerKey1 || bytes[at + 2] != kTrailerLength) {
    return {bytes, {}};
  }
  return {bytes.first(at), bytes.subspan(at + 3)};
}

PayloadAuthenticator::PayloadAuthenticator(const SessionKey& key, std::string domain,
                                           std::string session)
    : mac_(key), domain_(std::move(domain)), session_(std::move(session)) {}

bool PayloadAuthenticator::TagOf(std::span<const uint8_t> body, HmacSha256::Tag* tag) noexcept {
  uint8_t length[8];
  uint64_t n = session_.size();
  for (uint8_t& b : length) {
    b = static_cast<uint8_t>(n & 0xff);
    n >>= 8;
  }
  // The domain string includes its terminating NUL, so domain and length
  // cannot run into each other.
  return mac_.Begin() &&
         mac_.Update({reinterpret_cast<const uint8_t*>(domain_.c_str()), domain_.size() + 1}) &&
         mac_.Update(length) && mac_.Update(AsBytes(session_)) && mac_.Update(body) &&
         mac_.Final(tag);
}

bool PayloadAuthenticator::MakeTrailer(std::span<const uint8_t> body,
                                       std::span<uint8_t, kTrailerBytes> out) noexcept {
  HmacSha256::Tag tag;
  if (!TagOf(body, &tag)) return false;
  out[0] = kTrailerKey0;
  out[1] = kTrailerKey1;
  out[2] = kTrailerLength;
  std::copy(tag.begin(), tag.end(), out.begin() + 3);
  return true;
}

AuthVerdict PayloadAuthenticator::Check(std::span<const uint8_t> bytes,
                                        std::span<const uint8_t>* body) noexcept {
  const SignedBytes split = SplitTrailer(bytes);
  if (split.tag.empty()) return AuthVerdict::kUnsigned;
  HmacSha256::Tag tag;
  if (!TagOf(split.body, &tag)) return AuthVerdict::kForged;
  if (CRYPTO_memcmp(tag.data(), split.tag.data(), tag.size()) != 0) return AuthVerdict::kForged;
  *body = split.body;
  return AuthVerdict::kOk;
}

// ---- EpochGate ---------------------------------------------------------------------

const EpochGate::Seen* EpochGate::Find(uint64_t epoch) const noexcept {
  for (const Seen& s : seen_) {
    if (s.epoch == epoch && epoch != 0) return &s;
  }
  return nullptr;
}

EpochGate::Seen* EpochGate::Slot(uint64_t epoch) noexcept {
  for (Seen& s : seen_) {
    if (s.epoch == epoch) return &s;
  }
  // An empty entry, else the least recently heard epoch other than the followed one.
  Seen* pick = nullptr;
  for (Seen& s : seen_) {
    if (s.epoch == 0) {
      s = Seen{.epoch = epoch};
      return &s;
    }
    if (s.epoch == followed_) continue;
    if (pick == nullptr || s.last_mono_ns < pick->last_mono_ns) pick = &s;
  }
  *pick = Seen{.epoch = epoch};
  return pick;
}

AuthVerdict EpochGate::Judge(uint64_t epoch, uint64_t seq, int64_t wall_ns, int64_t now_wall_ns,
                             int64_t now_mono_ns, size_t lane) const noexcept {
  // An epoch is its sender's start time: never 0, never after a message it signed.
  if (lane >= kLanes || epoch == 0 || wall_ns < 0 || epoch > static_cast<uint64_t>(wall_ns)) {
    return AuthVerdict::kInvalidEpoch;
  }
  if (window_ns_ > 0) {
    const bool in_window = wall_ns <= now_wall_ns ? now_wall_ns - wall_ns <= window_ns_
                                                  : wall_ns - now_wall_ns <= window_ns_;
    if (!in_window) return AuthVerdict::kOutsideWindow;
  }
  const Seen* known = Find(epoch);
  if (known != nullptr && known->has[lane] && seq <= known->seq[lane]) return AuthVerdict::kReplayed;
  if (epoch == followed_) return AuthVerdict::kOk;
  if (followed_ != 0 && epoch < followed_) {
    const Seen* held = Find(followed_);
    const bool quiet = held == nullptr || now_mono_ns - held->last_mono_ns >= quiet_ns_;
    if (!quiet) return AuthVerdict::kOtherSender;
  }
  return AuthVerdict::kNewEpoch;
}

void EpochGate::Record(uint64_t epoch, uint64_t seq, int64_t now_mono_ns, size_t lane) noexcept {
  if (lane >= kLanes || epoch == 0) return;
  Seen* slot = Slot(epoch);
  followed_ = epoch;
  slot->seq[lane] = seq;
  slot->has[lane] = true;
  slot->last_mono_ns = now_mono_ns;
}

AuthVerdict EpochGate::Offer(uint64_t epoch, uint64_t seq, int64_t wall_ns, int64_t now_wall_ns,
                             int64_t now_mono_ns, size_t lane) noexcept {
  const AuthVerdict verdict = Judge(epoch, seq, wall_ns, now_wall_ns, now_mono_ns, lane);
  if (Accepted(verdict)) Record(epoch, seq, now_mono_ns, lane);
  return verdict;
}

}  // namespace cutsim::transport

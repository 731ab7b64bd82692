#include "common/transport/tool_auth.h"

#include <sys/stat.h>

#include <algorithm>
#include <bit>
#include <cctype>
#include <cstdlib>
#include <cstring>
#include <ctime>
#include <fstream>
#include <sstream>
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

// Domain separation: a tag for this message kind and version only.
constexpr char kDomain[] = "cutsim.v1.ToolState/hmac-sha256/1";

int64_t RealtimeNs() noexcept {
  timespec ts{};
  clock_gettime(CLOCK_REALTIME, &ts);
  return static_cast<int64_t>(ts.tv_sec) * 1'000'000'000 + ts.tv_nsec;
}

int HexValue(char c) {
  if (c >= '0' && c <= '9') return c - '0';
  if (c >= 'a' && c <= 'f') return c - 'a' + 10;
  if (c >= 'A' && c <= 'F') return c - 'A' + 10;
  return -1;
}

/// Little-endian writer into a fixed buffer.
class Canonical {
 public:
  void U64(uint64_t v) {
    for (int i = 0; i < 8; ++i) buf_[n_++] = static_cast<uint8_t>(v >> (8 * i));
  }
  void I64(int64_t v) { U64(static_cast<uint64_t>(v)); }
  void F64(double v) { U64(std::bit_cast<uint64_t>(v)); }
  void Vec(const v1::Vec3& v) {
    F64(v.x());
    F64(v.y());
    F64(v.z());
  }
  [[nodiscard]] const uint8_t* data() const { return buf_; }
  [[nodiscard]] size_t size() const { return n_; }

 private:
  uint8_t buf_[8 * 16] = {};
  size_t n_ = 0;
};

EVP_MAC_CTX* Ctx(void* p) { return static_cast<EVP_MAC_CTX*>(p); }

}  // namespace

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

HmacToolAuthenticator::HmacToolAuthenticator(const SessionKey& key, std::string session,
                                             int64_t window_ns)
    : session_(std::move(session)), window_ns_(window_ns) {
  EVP_MAC* mac = EVP_MAC_fetch(nullptr, "HMAC", nullptr);
  if (mac == nullptr) throw std::runtime_error("OpenSSL: HMAC is not available");
  mac_ = mac;
  EVP_MAC_CTX* ctx = EVP_MAC_CTX_new(mac);
  if (ctx == nullptr) {
    EVP_MAC_free(mac);
    throw std::runtime_error("OpenSSL: cannot create an HMAC context");
  }
  ctx_ = ctx;
  char digest[] = "SHA256";
  const OSSL_PARAM params[] = {
      OSSL_PARAM_construct_utf8_string(OSSL_MAC_PARAM_DIGEST, digest, 0),
      OSSL_PARAM_construct_end()};
  if (key.size < SessionKey::kMinBytes || EVP_MAC_init(ctx, key.bytes.data(), key.size, params) != 1) {
    EVP_MAC_CTX_free(ctx);
    EVP_MAC_free(mac);
    throw std::runtime_error("OpenSSL: cannot key HMAC-SHA256");
  }
  epoch_ = static_cast<uint64_t>(RealtimeNs());
}

HmacToolAuthenticator::~HmacToolAuthenticator() {
  EVP_MAC_CTX_free(Ctx(ctx_));
  EVP_MAC_free(static_cast<EVP_MAC*>(mac_));
}

bool HmacToolAuthenticator::Tag(const v1::ToolState& msg, uint8_t (&tag)[kTagBytes]) noexcept {
  EVP_MAC_CTX* ctx = Ctx(ctx_);
  // Re-initialise with the key set at construction (no key schedule again).
  if (EVP_MAC_init(ctx, nullptr, 0, nullptr) != 1) return false;
  Canonical c;
  c.U64(session_.size());
  if (EVP_MAC_update(ctx, reinterpret_cast<const uint8_t*>(kDomain), sizeof(kDomain)) != 1) return false;
  if (EVP_MAC_update(ctx, c.data(), c.size()) != 1) return false;
  if (EVP_MAC_update(ctx, reinterpret_cast<const uint8_t*>(session_.data()), session_.size()) != 1) {
    return false;
  }
  Canonical f;
  f.U64(msg.epoch());
  f.U64(msg.seq());
  f.I64(msg.stamp_ns());
  f.I64(msg.wall_ns());
  f.Vec(msg.tip());
  f.Vec(msg.blade_dir());
  f.Vec(msg.velocity());
  f.U64(msg.buttons());
  f.U64(msg.has_blade_dir() ? 1 : 0);  // absent and zero decode differently
  if (EVP_MAC_update(ctx, f.data(), f.size()) != 1) return false;
  size_t out = 0;
  return EVP_MAC_final(ctx, tag, &out, kTagBytes) == 1 && out == kTagBytes;
}

void HmacToolAuthenticator::Sign(v1::ToolState* msg) noexcept { SignAt(msg, RealtimeNs()); }

void HmacToolAuthenticator::SignAt(v1::ToolState* msg, int64_t now_wall_ns) noexcept {
  if (msg->seq() <= last_signed_seq_) {
    // A new stream on this authenticator: start a newer epoch.
    epoch_ = std::max(epoch_ + 1, static_cast<uint64_t>(now_wall_ns));
  }
  last_signed_seq_ = msg->seq();
  msg->set_epoch(epoch_);
  msg->set_wall_ns(now_wall_ns);
  uint8_t tag[kTagBytes];
  if (!Tag(*msg, tag)) {
    msg->clear_hmac();  // the server will count it as unsigned
    return;
  }
  try {
    // assign() reuses the string's storage after the first message
    // (set_hmac would build a temporary string each time).
    msg->mutable_hmac()->assign(reinterpret_cast<const char*>(tag), kTagBytes);
  } catch (...) {
    msg->clear_hmac();
  }
}

AuthVerdict HmacToolAuthenticator::Verify(const v1::ToolState& msg) noexcept {
  return VerifyAt(msg, RealtimeNs());
}

AuthVerdict HmacToolAuthenticator::VerifyAt(const v1::ToolState& msg, int64_t now_wall_ns) noexcept {
  if (msg.hmac().empty()) return AuthVerdict::kUnsigned;
  if (msg.hmac().size() != kTagBytes) return AuthVerdict::kForged;
  uint8_t tag[kTagBytes];
  if (!Tag(msg, tag)) return AuthVerdict::kForged;
  if (CRYPTO_memcmp(tag, msg.hmac().data(), kTagBytes) != 0) return AuthVerdict::kForged;
  // Authentic: now is it fresh? |now − wall| without overflow.
  const int64_t wall = msg.wall_ns();
  const bool in_window = wall <= now_wall_ns ? now_wall_ns - wall <= window_ns_
                                             : wall - now_wall_ns <= window_ns_;
  if (!in_window) return AuthVerdict::kOutsideWindow;
  AuthVerdict verdict = AuthVerdict::kOk;
  if (!have_ || msg.epoch() > held_epoch_) {
    verdict = AuthVerdict::kNewEpoch;
  } else if (msg.epoch() < held_epoch_ || msg.seq() <= held_seq_) {
    return AuthVerdict::kReplayed;
  }
  have_ = true;
  held_epoch_ = msg.epoch();
  held_seq_ = msg.seq();
  return verdict;
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
  }
  return "?";
}

}  // namespace cutsim::transport

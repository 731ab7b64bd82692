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

}  // namespace

HmacToolAuthenticator::HmacToolAuthenticator(const SessionKey& key, std::string session,
                                             int64_t window_ns)
    : session_(std::move(session)),
      mac_(key),
      epoch_(static_cast<uint64_t>(RealtimeNowNs())),
      gate_(window_ns) {}

HmacToolAuthenticator::~HmacToolAuthenticator() = default;

bool HmacToolAuthenticator::Tag(const v1::ToolState& msg, HmacSha256::Tag* tag) noexcept {
  Canonical c;
  c.U64(session_.size());
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
  return mac_.Begin() &&
         mac_.Update({reinterpret_cast<const uint8_t*>(kDomain), sizeof(kDomain)}) &&
         mac_.Update({c.data(), c.size()}) &&
         mac_.Update({reinterpret_cast<const uint8_t*>(session_.data()), session_.size()}) &&
         mac_.Update({f.data(), f.size()}) && mac_.Final(tag);
}

void HmacToolAuthenticator::Sign(v1::ToolState* msg) noexcept { SignAt(msg, RealtimeNowNs()); }

void HmacToolAuthenticator::SignAt(v1::ToolState* msg, int64_t now_wall_ns) noexcept {
  if (msg->seq() <= last_signed_seq_) {
    // A new stream on this authenticator: start a newer epoch.
    epoch_ = std::max(epoch_ + 1, static_cast<uint64_t>(now_wall_ns));
  }
  last_signed_seq_ = msg->seq();
  msg->set_epoch(epoch_);
  msg->set_wall_ns(now_wall_ns);
  HmacSha256::Tag tag;
  if (!Tag(*msg, &tag)) {
    msg->clear_hmac();  // the server will count it as unsigned
    return;
  }
  try {
    // assign() reuses the string's storage after the first message
    // (set_hmac would build a temporary string each time).
    msg->mutable_hmac()->assign(reinterpret_cast<const char*>(tag.data()), kTagBytes);
  } catch (...) {
    msg->clear_hmac();
  }
}

AuthVerdict HmacToolAuthenticator::Verify(const v1::ToolState& msg) noexcept {
  timespec mono{};
  clock_gettime(CLOCK_MONOTONIC, &mono);
  return VerifyAt(msg, RealtimeNowNs(),
                  static_cast<int64_t>(mono.tv_sec) * 1'000'000'000 + mono.tv_nsec);
}

AuthVerdict HmacToolAuthenticator::VerifyAt(const v1::ToolState& msg, int64_t now_wall_ns,
                                            std::optional<int64_t> now_mono_ns) noexcept {
  if (msg.hmac().empty()) return AuthVerdict::kUnsigned;
  if (msg.hmac().size() != kTagBytes) return AuthVerdict::kForged;
  HmacSha256::Tag tag;
  if (!Tag(msg, &tag)) return AuthVerdict::kForged;
  if (CRYPTO_memcmp(tag.data(), msg.hmac().data(), kTagBytes) != 0) return AuthVerdict::kForged;
  return gate_.Offer(msg.epoch(), msg.seq(), msg.wall_ns(), now_wall_ns,
                     now_mono_ns.value_or(now_wall_ns));
}

}  // namespace cutsim::transport

// Access control of tool messages: HMAC-SHA256 signing and verification,
// rejection of unsigned, forged, foreign-session and replayed messages, key
// parsing, the server link's counters, and what signing allocates.
#include "common/transport/tool_auth.h"

#include <openssl/crypto.h>

#include <atomic>
#include <cstdlib>
#include <ctime>
#include <filesystem>
#include <fstream>
#include <new>
#include <string>

#include <gtest/gtest.h>

#include "common/core/clock.h"
#include "common/core/error.h"
#include "common/transport/channels.h"
#include "common/transport/codec.h"
#include "common/transport/lcm_bus.h"

// ---- Allocation counters: C++ (operator new) and OpenSSL (CRYPTO_malloc). ----
namespace {
std::atomic<long> g_new_calls{0};
std::atomic<long> g_ossl_calls{0};
void* OsslMalloc(size_t n, const char*, int) {
  g_ossl_calls.fetch_add(1, std::memory_order_relaxed);
  return std::malloc(n);
}
void* OsslRealloc(void* p, size_t n, const char*, int) {
  g_ossl_calls.fetch_add(1, std::memory_order_relaxed);
  return std::realloc(p, n);
}
void OsslFree(void* p, const char*, int) { std::free(p); }
// Before OpenSSL allocates anything (static initialisation of this binary).
const bool g_ossl_hooked = CRYPTO_set_mem_functions(OsslMalloc, OsslRealloc, OsslFree) == 1;
}  // namespace

void* operator new(std::size_t size) {
  g_new_calls.fetch_add(1, std::memory_order_relaxed);
  if (void* p = std::malloc(size == 0 ? 1 : size)) return p;
  throw std::bad_alloc();
}
// Every other form too, so that memory from any of them (libraries linked in
// use the nothrow and array forms) is released by the matching std::free —
// a partial replacement is an alloc-dealloc mismatch under ASan.
void* operator new[](std::size_t size) { return operator new(size); }
void* operator new(std::size_t size, const std::nothrow_t&) noexcept {
  g_new_calls.fetch_add(1, std::memory_order_relaxed);
  return std::malloc(size == 0 ? 1 : size);
}
void* operator new[](std::size_t size, const std::nothrow_t& tag) noexcept { return operator new(size, tag); }
void operator delete(void* p) noexcept { std::free(p); }
void operator delete(void* p, std::size_t) noexcept { std::free(p); }
void operator delete[](void* p) noexcept { std::free(p); }
void operator delete[](void* p, std::size_t) noexcept { std::free(p); }
void operator delete(void* p, const std::nothrow_t&) noexcept { std::free(p); }
void operator delete[](void* p, const std::nothrow_t&) noexcept { std::free(p); }

namespace cutsim::transport {
namespace {

constexpr int64_t kSecond = 1'000'000'000;

SessionKey Key(uint8_t fill = 0x42) {
  SessionKey k;
  k.size = 32;
  for (size_t i = 0; i < k.size; ++i) k.bytes[i] = static_cast<uint8_t>(fill + i);
  return k;
}

v1::ToolState Tool(const std::string& session, uint64_t seq, double z = 0.01) {
  v1::ToolState t;
  t.set_session(session);
  t.set_seq(seq);
  t.set_stamp_ns(1000 * static_cast<int64_t>(seq));
  t.mutable_tip()->set_z(z);
  t.mutable_blade_dir()->set_z(1.0);
  t.set_buttons(1);
  return t;
}

int64_t WallNs() {
  timespec ts{};
  clock_gettime(CLOCK_REALTIME, &ts);
  return static_cast<int64_t>(ts.tv_sec) * kSecond + ts.tv_nsec;
}

TEST(SessionKeyTest, ParsesHexAndRejectsBadKeys) {
  const SessionKey k = ParseSessionKey(" 00112233445566778899aabbccddeeff\n", "key.txt");
  ASSERT_EQ(k.size, 16u);
  EXPECT_EQ(k.bytes[0], 0x00);
  EXPECT_EQ(k.bytes[15], 0xff);
  EXPECT_EQ(ParseSessionKey(std::string(128, 'A'), "k").size, 64u);
  // Short, odd, non-hex, too long: each an InputError naming the source.
  for (const std::string& bad : {std::string(30, 'a'), std::string(33, 'a'), std::string(31, 'a') + "g",
                                std::string(130, 'a')}) {
    try {
      (void)ParseSessionKey(bad, "lab.key");
      ADD_FAILURE() << "accepted " << bad.size() << " characters";
    } catch (const InputError& e) {
      EXPECT_NE(std::string(e.what()).find("lab.key"), std::string::npos) << e.what();
      EXPECT_EQ(std::string(e.what()).find("aaaaaaaa"), std::string::npos) << "error quotes the key";
    }
  }
}

TEST(SessionKeyTest, FileWinsOverEnvironmentAndNoneIsOpen) {
  const auto dir = std::filesystem::temp_directory_path() / ("tool_auth_" + std::to_string(::getpid()));
  std::filesystem::create_directories(dir);
  const auto file = dir / "session.key";
  std::ofstream(file) << std::string(64, 'b') << "\n";
  std::filesystem::permissions(file, std::filesystem::perms::owner_read | std::filesystem::perms::owner_write);
  ::setenv(kSessionKeyEnv, std::string(64, 'c').c_str(), 1);
  auto k = LoadSessionKey(file.string());
  ASSERT_TRUE(k.has_value());
  EXPECT_EQ(k->bytes[0], 0xbb);
  k = LoadSessionKey("");
  ASSERT_TRUE(k.has_value());
  EXPECT_EQ(k->bytes[0], 0xcc);
  ::unsetenv(kSessionKeyEnv);
  EXPECT_FALSE(LoadSessionKey("").has_value());
  EXPECT_THROW((void)LoadSessionKey((dir / "missing.key").string()), InputError);
  std::filesystem::remove_all(dir);
}

TEST(HmacToolAuthenticatorTest, SignedMessagesVerifyAndTamperingIsForged) {
  HmacToolAuthenticator client(Key(), "lab");
  HmacToolAuthenticator server(Key(), "lab");
  const int64_t now = WallNs();
  v1::ToolState t = Tool("lab", 1);
  client.SignAt(&t, now);
  EXPECT_EQ(t.hmac().size(), HmacToolAuthenticator::kTagBytes);
  EXPECT_EQ(t.epoch(), client.epoch());
  // Round trip through the wire encoding.
  Encoder enc;
  const auto bytes = enc.Encode(t);
  ASSERT_TRUE(bytes);
  v1::ToolState received;
  ASSERT_TRUE(DecodeInto(*bytes, received, "test"));
  EXPECT_EQ(server.VerifyAt(received, now), AuthVerdict::kNewEpoch);

  // Each covered field altered after signing: forged (and the held state is
  // not advanced by forgeries, so the genuine next message still passes).
  uint64_t seq = 1;
  const auto tampered = [&](auto mutate) {
    v1::ToolState m = Tool("lab", ++seq);
    client.SignAt(&m, now);
    mutate(m);
    return server.VerifyAt(m, now);
  };
  EXPECT_EQ(tampered([](v1::ToolState& m) { m.mutable_tip()->set_z(0.02); }), AuthVerdict::kForged);
  EXPECT_EQ(tampered([](v1::ToolState& m) { m.set_seq(m.seq() + 1); }), AuthVerdict::kForged);
  EXPECT_EQ(tampered([](v1::ToolState& m) { m.set_stamp_ns(m.stamp_ns() + 1); }), AuthVerdict::kForged);
  EXPECT_EQ(tampered([](v1::ToolState& m) { m.set_wall_ns(m.wall_ns() + 1); }), AuthVerdict::kForged);
  EXPECT_EQ(tampered([](v1::ToolState& m) { m.set_epoch(m.epoch() + 1); }), AuthVerdict::kForged);
  EXPECT_EQ(tampered([](v1::ToolState& m) { m.set_buttons(0); }), AuthVerdict::kForged);
  EXPECT_EQ(tampered([](v1::ToolState& m) { m.mutable_velocity()->set_x(1.0); }), AuthVerdict::kForged);
  EXPECT_EQ(tampered([](v1::ToolState& m) { m.clear_blade_dir(); }), AuthVerdict::kForged);
  EXPECT_EQ(tampered([](v1::ToolState& m) { m.mutable_hmac()->at(5) ^= 1; }), AuthVerdict::kForged);
  EXPECT_EQ(tampered([](v1::ToolState& m) { m.mutable_hmac()->resize(16); }), AuthVerdict::kForged);
  EXPECT_EQ(tampered([](v1::ToolState& m) { m.clear_hmac(); }), AuthVerdict::kUnsigned);

  v1::ToolState next = Tool("lab", ++seq);
  client.SignAt(&next, now);
  EXPECT_EQ(server.VerifyAt(next, now), AuthVerdict::kOk);
}

TEST(HmacToolAuthenticatorTest, WrongKeyAndForeignSessionAreForged) {
  const int64_t now = WallNs();
  HmacToolAuthenticator server(Key(), "lab");
  HmacToolAuthenticator intruder(Key(0x17), "lab");  // guessed key
  v1::ToolState t = Tool("lab", 1);
  intruder.SignAt(&t, now);
  EXPECT_EQ(server.VerifyAt(t, now), AuthVerdict::kForged);
  // Signed with the right key for another session: the session is in the tag.
  HmacToolAuthenticator other_session(Key(), "other");
  v1::ToolState o = Tool("lab", 1);
  other_session.SignAt(&o, now);
  EXPECT_EQ(server.VerifyAt(o, now), AuthVerdict::kForged);
}

TEST(HmacToolAuthenticatorTest, ReplaysAndOldMessagesAreRejected) {
  HmacToolAuthenticator client(Key(), "lab");
  HmacToolAuthenticator server(Key(), "lab", /*window_ns=*/2 * kSecond);
  const int64_t now = WallNs();
  v1::ToolState m[4];
  for (int i = 0; i < 4; ++i) {
    m[i] = Tool("lab", static_cast<uint64_t>(i + 1));
    client.SignAt(&m[i], now + i);
  }
  EXPECT_EQ(server.VerifyAt(m[0], now), AuthVerdict::kNewEpoch);
  EXPECT_EQ(server.VerifyAt(m[2], now), AuthVerdict::kOk);  // gaps are fine (loss)
  EXPECT_EQ(server.VerifyAt(m[2], now), AuthVerdict::kReplayed);  // duplicate
  EXPECT_EQ(server.VerifyAt(m[1], now), AuthVerdict::kReplayed);  // older
  EXPECT_EQ(server.VerifyAt(m[3], now), AuthVerdict::kOk);

  // A correctly signed message whose clock is far off (a recording replayed
  // to a fresh server, or a sender with a wrong clock).
  HmacToolAuthenticator fresh_server(Key(), "lab", 2 * kSecond);
  EXPECT_EQ(fresh_server.VerifyAt(m[3], now + 3 * kSecond), AuthVerdict::kOutsideWindow);
  EXPECT_EQ(fresh_server.VerifyAt(m[3], now - 3 * kSecond), AuthVerdict::kOutsideWindow);
  EXPECT_EQ(fresh_server.VerifyAt(m[3], now + kSecond), AuthVerdict::kNewEpoch);

  // A restarted sender (new authenticator: newer epoch) is accepted with seq 1;
  // the old epoch's messages are then refused while the new sender is heard.
  HmacToolAuthenticator restarted(Key(), "lab");
  ASSERT_GT(restarted.epoch(), client.epoch());
  const int64_t later = static_cast<int64_t>(restarted.epoch());
  v1::ToolState r = Tool("lab", 1);
  restarted.SignAt(&r, later + 10);
  EXPECT_EQ(server.VerifyAt(r, later), AuthVerdict::kNewEpoch);
  v1::ToolState late = Tool("lab", 5);
  client.SignAt(&late, later + 11);
  EXPECT_EQ(server.VerifyAt(late, later), AuthVerdict::kOtherSender);

  // Reusing an authenticator for a new stream (seq back to 1) moves to a new epoch.
  const uint64_t before = restarted.epoch();
  v1::ToolState again = Tool("lab", 1);
  restarted.SignAt(&again, later + 1000);
  EXPECT_GT(again.epoch(), before);
  EXPECT_EQ(server.VerifyAt(again, later), AuthVerdict::kNewEpoch);
}

TEST(HmacToolAuthenticatorTest, NoSingleMessageLocksTheStationOut) {
  HmacToolAuthenticator station(Key(), "lab");
  HmacToolAuthenticator server(Key(), "lab", 2 * kSecond);
  const int64_t t0 = static_cast<int64_t>(station.epoch()) + kSecond;
  v1::ToolState m = Tool("lab", 1);
  station.SignAt(&m, t0);
  ASSERT_EQ(server.VerifyAt(m, t0), AuthVerdict::kNewEpoch);

  // A newer authentic epoch takes the stream; the station is refused only
  // while that sender is heard, and takes over again once it is quiet.
  HmacToolAuthenticator newer(Key(), "lab");
  v1::ToolState n = Tool("lab", 1);
  const int64_t t1 = static_cast<int64_t>(newer.epoch()) + 1;
  newer.SignAt(&n, t1);
  ASSERT_EQ(server.VerifyAt(n, t1, t1), AuthVerdict::kNewEpoch);
  v1::ToolState s2 = Tool("lab", 2);
  station.SignAt(&s2, t1 + 1000);
  EXPECT_EQ(server.VerifyAt(s2, t1 + 1000, t1 + 1000), AuthVerdict::kOtherSender);
  const int64_t quiet = t1 + EpochGate::kDefaultQuietNs + 1;
  v1::ToolState s3 = Tool("lab", 3);
  station.SignAt(&s3, quiet);
  EXPECT_EQ(server.VerifyAt(s3, quiet, quiet), AuthVerdict::kNewEpoch);
  // And its replay memory survived the detour.
  EXPECT_EQ(server.VerifyAt(s2, quiet, quiet), AuthVerdict::kReplayed);
}

// The server end of the link counts each kind of rejection and passes only
// authentic, fresh poses (memq://, in-process LCM).
TEST(HapticServerLinkAuthTest, CountsUnsignedForgedReplayedAndForeign) {
  LcmBus bus("memq://");
  HmacToolAuthenticator server_auth(Key(), "lab");
  HapticServerLink link(bus, "lab", {.authenticator = &server_auth});
  HmacToolAuthenticator client(Key(), "lab");
  HmacToolAuthenticator intruder(Key(0x99), "lab");
  const std::string channel = LcmChannelName("lab", LcmChannel::kTool);
  Encoder enc;
  // One message per poll: the bus keeps only the newest per channel.
  const auto send = [&](const v1::ToolState& t) {
    const auto bytes = enc.Encode(t);
    ASSERT_TRUE(bytes);
    ASSERT_EQ(bus.PublishBytes(channel, *bytes), PublishStatus::kOk);
    EXPECT_FALSE(link.PollTool().has_value()) << "a rejected message reached the tool";
  };
  v1::ToolState good = Tool("lab", 1, 0.02);
  client.Sign(&good);
  ASSERT_EQ(bus.PublishBytes(channel, *enc.Encode(good)), PublishStatus::kOk);
  auto polled = link.PollTool();
  ASSERT_TRUE(polled.has_value());
  EXPECT_DOUBLE_EQ(polled->pose.tip.z(), 0.02);

  send(Tool("lab", 2, 0.5));                 // unsigned
  v1::ToolState forged = Tool("lab", 3, 0.5);
  intruder.Sign(&forged);
  send(forged);                              // wrong key
  send(good);                                // replayed
  v1::ToolState foreign = Tool("elsewhere", 4, 0.5);
  client.Sign(&foreign);
  send(foreign);                             // foreign session
  ASSERT_TRUE(link.latest_tool().has_value());
  EXPECT_DOUBLE_EQ(link.latest_tool()->pose.tip.z(), 0.02);  // the attacker never moved the tool

  const HapticServerLinkStats s = link.stats();
  EXPECT_EQ(s.accepted, 1u);
  EXPECT_EQ(s.auth_unsigned, 1u);
  EXPECT_EQ(s.auth_forged, 1u);
  EXPECT_EQ(s.auth_replayed, 1u);
  EXPECT_EQ(s.foreign_session, 1u);
  EXPECT_EQ(s.unauthenticated, 3u);

  v1::ToolState next = Tool("lab", 2, 0.03);
  client.Sign(&next);
  ASSERT_EQ(bus.PublishBytes(channel, *enc.Encode(next)), PublishStatus::kOk);
  polled = link.PollTool();
  ASSERT_TRUE(polled.has_value());
  EXPECT_DOUBLE_EQ(polled->pose.tip.z(), 0.03);
}

// Signing and verifying allocate nothing through C++ (protobuf reuses the
// tag's storage), and through OpenSSL only its fixed per-message re-init
// cost (digest-context duplication in OpenSSL 3's HMAC), never growing.
TEST(HmacToolAuthenticatorTest, SteadyStateAllocationsAreBounded) {
  ASSERT_TRUE(g_ossl_hooked) << "OpenSSL allocated before the counters were installed";
  HmacToolAuthenticator client(Key(), "lab");
  HmacToolAuthenticator server(Key(), "lab");
  v1::ToolState t = Tool("lab", 1);
  const int64_t now = WallNs();
  for (uint64_t i = 1; i <= 10; ++i) {  // warm up
    t.set_seq(i);
    client.SignAt(&t, now);
    ASSERT_NE(server.VerifyAt(t, now), AuthVerdict::kForged);
  }
  constexpr int kMessages = 1000;
  const long new0 = g_new_calls.load();
  const long ossl0 = g_ossl_calls.load();
  for (uint64_t i = 11; i < 11 + kMessages; ++i) {
    t.set_seq(i);
    client.SignAt(&t, now);
    ASSERT_EQ(server.VerifyAt(t, now), AuthVerdict::kOk);
  }
  const long cxx = g_new_calls.load() - new0;
  const double ossl_per_op = static_cast<double>(g_ossl_calls.load() - ossl0) / (2.0 * kMessages);
  std::printf("allocations per sign or verify: C++ %.3f, OpenSSL %.3f\n",
              static_cast<double>(cxx) / (2.0 * kMessages), ossl_per_op);
  EXPECT_EQ(cxx, 0);
  EXPECT_LE(ossl_per_op, 2.0);  // measured: 2 (HMAC re-init + final each dup a digest ctx)
}

}  // namespace
}  // namespace cutsim::transport

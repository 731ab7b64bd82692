// LCM event logs: round trip, and hostile headers (lengths over the caps or
// past the end of the file) refused before anything is read or allocated.

#include "common/transport/lcm_log.h"

#include <unistd.h>

#include <cstdint>
#include <filesystem>
#include <fstream>
#include <string>
#include <vector>

#include <gtest/gtest.h>

#include "common/core/error.h"

namespace cutsim::transport {
namespace {

class LcmLogTest : public ::testing::Test {
 protected:
  void SetUp() override {
    path_ = std::filesystem::temp_directory_path() /
            ("cutsim_lcm_log_" + std::to_string(::getpid()) + "_" +
             ::testing::UnitTest::GetInstance()->current_test_info()->name() + ".lcm");
  }
  void TearDown() override { std::filesystem::remove(path_); }

  /// A log of two events, as bytes.
  std::string TwoEvents() {
    {
      LcmLogWriter w(path_);
      const std::vector<uint8_t> a{1, 2, 3}, b(100, 7);
      w.Write("CUTSIM_A", a, 10);
      w.Write("CUTSIM_B", b, 20);
      w.Close();
    }
    std::ifstream in(path_, std::ios::binary);
    return {std::istreambuf_iterator<char>(in), std::istreambuf_iterator<char>()};
  }
  void Overwrite(const std::string& bytes) { std::ofstream(path_, std::ios::binary | std::ios::trunc) << bytes; }

  std::filesystem::path path_;
};

/// Sets the big-endian int32 at `offset`.
void PutBe32(std::string& s, size_t offset, uint32_t v) {
  for (int i = 0; i < 4; ++i) s[offset + static_cast<size_t>(i)] = static_cast<char>((v >> (24 - 8 * i)) & 0xff);
}

constexpr size_t kChannelLenOffset = 20, kDataLenOffset = 24;

TEST_F(LcmLogTest, RoundTrip) {
  TwoEvents();
  LcmLogReader r(path_);
  auto a = r.Next();
  ASSERT_TRUE(a);
  EXPECT_EQ(a->channel, "CUTSIM_A");
  EXPECT_EQ(a->data, (std::vector<uint8_t>{1, 2, 3}));
  EXPECT_EQ(a->timestamp_us, 10);
  auto b = r.Next();
  ASSERT_TRUE(b);
  EXPECT_EQ(b->eventnum, 1);
  EXPECT_EQ(b->data.size(), 100u);
  EXPECT_FALSE(r.Next());
}

TEST_F(LcmLogTest, AHugeDataLengthIsRefusedNamingTheEvent) {
  std::string bytes = TwoEvents();
  PutBe32(bytes, kDataLenOffset, 0x7fffffff);  // 2 GB
  Overwrite(bytes);
  LcmLogReader r(path_);
  try {
    (void)r.Next();
    FAIL() << "expected InputError";
  } catch (const InputError& e) {
    EXPECT_EQ(e.source().file, path_.string());
    EXPECT_EQ(e.source().field, "event 0 (byte 0)");
    EXPECT_NE(std::string(e.what()).find("2147483647"), std::string::npos) << e.what();
  }
  PutBe32(bytes, kDataLenOffset, 0x80000000);  // negative
  Overwrite(bytes);
  LcmLogReader r2(path_);
  EXPECT_THROW((void)r2.Next(), InputError);
  bytes = TwoEvents();
  PutBe32(bytes, kChannelLenOffset, 1u << 20);
  Overwrite(bytes);
  LcmLogReader r3(path_);
  EXPECT_THROW((void)r3.Next(), InputError);
}

TEST_F(LcmLogTest, ALengthPastTheEndIsATruncatedTail) {
  std::string bytes = TwoEvents();
  bytes.resize(bytes.size() - 10);
  Overwrite(bytes);
  LcmLogReader r(path_);
  EXPECT_TRUE(r.Next());
  EXPECT_FALSE(r.Next());
}

TEST_F(LcmLogTest, NonRegularFilesAreRefused) {
  EXPECT_THROW(LcmLogReader("/dev/zero"), InputError);
  EXPECT_THROW(LcmLogReader{std::filesystem::temp_directory_path()}, InputError);
}

TEST_F(LcmLogTest, WritesToAFullDeviceFailLoudly) {
  LcmLogWriter w("/dev/full");
  const std::vector<uint8_t> data(64, 1);
  w.Write("CUTSIM_A", data, 1);  // buffered
  EXPECT_THROW(w.Flush(), InputError);
  EXPECT_THROW(w.Close(), InputError);
}

}  // namespace
}  // namespace cutsim::transport

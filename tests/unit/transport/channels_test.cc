#include "common/transport/channels.h"

#include <string>

#include <gtest/gtest.h>

#include "common/core/error.h"

namespace cutsim::transport {
namespace {

TEST(ChannelsTest, LcmChannelNamesComeFromOneHelper) {
  EXPECT_EQ(LcmChannelName("lab1", LcmChannel::kTool), "CUTSIM_lab1_TOOL");
  EXPECT_EQ(LcmChannelName("lab1", LcmChannel::kModel), "CUTSIM_lab1_MODEL");
}

TEST(ChannelsTest, SessionNamesThatCouldActAsRegexOrOverflowAreRejected) {
  EXPECT_TRUE(IsValidSessionName("a-b_C9"));
  EXPECT_FALSE(IsValidSessionName(""));
  EXPECT_FALSE(IsValidSessionName("a.b"));
  EXPECT_FALSE(IsValidSessionName("a*"));
  EXPECT_FALSE(IsValidSessionName("a b"));
  EXPECT_TRUE(IsValidSessionName(std::string(kMaxSessionLength, 'x')));
  EXPECT_FALSE(IsValidSessionName(std::string(kMaxSessionLength + 1, 'x')));
  // The longest channel still fits LCM's 63-character limit.
  EXPECT_LE(LcmChannelName(std::string(kMaxSessionLength, 'x'), LcmChannel::kModel).size(), 63U);
}

TEST(ChannelsTest, InvalidSessionErrorNamesTheFlag) {
  try {
    static_cast<void>(LcmChannelName("bad.session", LcmChannel::kTool));
    FAIL() << "no throw";
  } catch (const InputError& e) {
    EXPECT_EQ(e.source().field, "--session");
    EXPECT_NE(std::string(e.what()).find("bad.session"), std::string::npos);
  }
}

TEST(ChannelsTest, DefaultLcmUrlStaysOnThisHost) {
  EXPECT_NE(std::string(kDefaultLcmUrl).find("ttl=0"), std::string::npos);
}

}  // namespace
}  // namespace cutsim::transport

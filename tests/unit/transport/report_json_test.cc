// The applications' reports print as valid one-line JSON whose keys are the
// .proto field names, with every field present and counts as JSON numbers.

#include "common/transport/report_json.h"

#include <cmath>
#include <cstdint>
#include <limits>
#include <string>

#include <google/protobuf/util/json_util.h>
#include <google/protobuf/util/message_differencer.h>
#include <gtest/gtest.h>

#include "cutsim/v1/report.pb.h"

namespace cutsim::transport {
namespace {

using google::protobuf::util::MessageDifferencer;

v1::ViewerSummary SampleSummary() {
  v1::ViewerSummary v;
  v.set_session("s-1");
  v.set_frames(42);
  v.set_verified_frames(42);
  v.set_bytes_received(6e9);  // above 2^32: a double keeps it exact
  v.set_join_latency_s(0.25);
  v.set_first_seq(1.7e12);
  v.set_first_hash(HexHash(0x0123456789abcdefULL));
  v.set_exit_reason("signal");
  return v;
}

TEST(ReportJsonTest, ParsesBackToTheSameMessage) {
  const v1::ViewerSummary original = SampleSummary();
  const std::string json = ReportJson(original);
  v1::ViewerSummary parsed;
  ASSERT_TRUE(google::protobuf::util::JsonStringToMessage(json, &parsed).ok()) << json;
  EXPECT_TRUE(MessageDifferencer::Equals(original, parsed)) << json;
}

TEST(ReportJsonTest, OneLineWithProtoFieldNamesAndEveryField) {
  const std::string json = ReportJson(v1::ServerSessionStats{});
  EXPECT_EQ(json.find('\n'), std::string::npos);
  // Field names as written in the .proto, not lowerCamelCase.
  EXPECT_NE(json.find("\"frame_time_p99_ms\":0"), std::string::npos) << json;
  EXPECT_EQ(json.find("frameTimeP99Ms"), std::string::npos) << json;
  // Zero counts, false and empty strings are printed too; a message field
  // (the measures, the score) is printed when the report carries it.
  const auto* d = v1::ServerSessionStats::descriptor();
  for (int i = 0; i < d->field_count(); ++i) {
    if (d->field(i)->type() == google::protobuf::FieldDescriptor::TYPE_MESSAGE) continue;
    EXPECT_NE(json.find("\"" + d->field(i)->name() + "\":"), std::string::npos) << d->field(i)->name();
  }
  v1::ServerSessionStats with_score;
  with_score.mutable_score();
  EXPECT_NE(ReportJson(with_score).find("\"score\":{\"cut_points\":0"), std::string::npos) << ReportJson(with_score);
}

TEST(ReportJsonTest, CountsAreJsonNumbersNotStrings) {
  v1::HapticStats stats;
  stats.set_kind("haptic_stats");
  stats.set_ticks(ReportCount(uint64_t{5000}));
  stats.mutable_link()->set_restarts(2);
  const std::string json = ReportJson(stats);
  EXPECT_EQ(json.rfind("{\"kind\":\"haptic_stats\",", 0), 0u) << json;  // kind first
  EXPECT_NE(json.find("\"ticks\":5000"), std::string::npos) << json;
  EXPECT_NE(json.find("\"link\":{\"tools_written\":0"), std::string::npos) << json;
  EXPECT_NE(json.find("\"restarts\":2"), std::string::npos) << json;
}

TEST(ReportJsonTest, NonFiniteNumbersAndOddStringsStayValidJson) {
  v1::HeadlessSummary s;
  s.set_kinetic_energy(std::numeric_limits<double>::quiet_NaN());
  s.set_residual_force(std::numeric_limits<double>::infinity());
  s.set_diagnosis("quote \" backslash \\ newline \n tab \t control \x01 end");
  const std::string json = ReportJson(s);
  EXPECT_EQ(json.find('\n'), std::string::npos) << json;
  EXPECT_NE(json.find("\"kinetic_energy\":\"NaN\""), std::string::npos) << json;
  EXPECT_NE(json.find("\"residual_force\":\"Infinity\""), std::string::npos) << json;
  v1::HeadlessSummary parsed;
  ASSERT_TRUE(google::protobuf::util::JsonStringToMessage(json, &parsed).ok()) << json;
  EXPECT_EQ(parsed.diagnosis(), s.diagnosis());
  EXPECT_TRUE(std::isnan(parsed.kinetic_energy()));
  EXPECT_TRUE(std::isinf(parsed.residual_force()));
}

TEST(ReportJsonTest, InvalidUtf8NamesBecomeReplacementCharacters) {
  v1::ViewerSummary v = SampleSummary();
  // A lone continuation byte, a truncated sequence, an overlong '/', a
  // surrogate and a byte that never starts UTF-8, around valid text.
  v.set_session(std::string("lab\x80-\xE2\x82-\xC0\xAF-\xED\xA0\x80-\xFF \"q\"\n\xC3\xA9"));
  v.set_exit_reason(std::string("\0nul", 4));
  const std::string json = ReportJson(v);
  ASSERT_NE(json, "{}") << "the printer refused the message";
  v1::ViewerSummary parsed;
  ASSERT_TRUE(google::protobuf::util::JsonStringToMessage(json, &parsed).ok()) << json;
  EXPECT_EQ(parsed.session().rfind("lab\xEF\xBF\xBD", 0), 0u) << parsed.session();
  EXPECT_NE(parsed.session().find("\"q\"\n\xC3\xA9"), std::string::npos) << "valid text is kept";
  EXPECT_EQ(parsed.session(), ValidUtf8(parsed.session())) << "the result is valid UTF-8";
  EXPECT_EQ(parsed.exit_reason(), v.exit_reason());
  EXPECT_EQ(parsed.frames(), v.frames());
}

TEST(ReportJsonTest, ValidUtf8KeepsValidTextAndReplacesEachBadByte) {
  EXPECT_EQ(ValidUtf8("plain ascii"), "plain ascii");
  EXPECT_EQ(ValidUtf8("\xF0\x9F\x94\xAA knife"), "\xF0\x9F\x94\xAA knife");
  EXPECT_EQ(ValidUtf8("a\xFF" "b"), "a\xEF\xBF\xBD" "b");
  EXPECT_EQ(ValidUtf8("\xE2\x82"), "\xEF\xBF\xBD\xEF\xBF\xBD");
}

TEST(ReportJsonTest, ReportCountSaturatesInsteadOfWrapping) {
  EXPECT_EQ(ReportCount(uint64_t{7}), 7u);
  EXPECT_EQ(ReportCount(int64_t{-3}), 0u);
  EXPECT_EQ(ReportCount(uint64_t{1} << 32), std::numeric_limits<uint32_t>::max());
  EXPECT_EQ(ReportCount(std::numeric_limits<int64_t>::max()), std::numeric_limits<uint32_t>::max());
  EXPECT_EQ(ReportCount(int{123}), 123u);
}

TEST(ReportJsonTest, HexHashIsSixteenLowerCaseDigits) {
  EXPECT_EQ(HexHash(0), "0000000000000000");
  EXPECT_EQ(HexHash(0xABCDEF0123456789ULL), "abcdef0123456789");
}

}  // namespace
}  // namespace cutsim::transport

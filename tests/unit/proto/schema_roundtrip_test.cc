// Every message of the wire and scene schemas survives serialise → parse
// unchanged with every field set. Fields are filled by reflection, so a
// field added to a .proto is covered without touching this test; every
// alternative of every oneof gets its own round trip.

#include <algorithm>
#include <cstdint>
#include <memory>
#include <string>
#include <vector>

#include <google/protobuf/descriptor.h>
#include <google/protobuf/message.h>
#include <google/protobuf/util/message_differencer.h>
#include <gtest/gtest.h>

#include "cutsim/v1/geometry.pb.h"
#include "cutsim/v1/scene.pb.h"
#include "cutsim/v1/wire.pb.h"

namespace cutsim {
namespace {

using google::protobuf::Descriptor;
using google::protobuf::FieldDescriptor;
using google::protobuf::FileDescriptor;
using google::protobuf::Message;
using google::protobuf::MessageFactory;
using google::protobuf::Reflection;
using google::protobuf::util::MessageDifferencer;

constexpr int kRepeatCount = 3;
constexpr int kMaxDepth = 4;

/// Fills every field of `msg` with non-default values derived from `salt`.
/// For each oneof, only the alternative `choice % field_count` is set.
void FillAllFields(Message* msg, int choice, uint64_t salt, int depth) {
  const Descriptor* d = msg->GetDescriptor();
  const Reflection* r = msg->GetReflection();
  for (int i = 0; i < d->field_count(); ++i) {
    const FieldDescriptor* f = d->field(i);
    if (const auto* oneof = f->real_containing_oneof()) {
      if (oneof->field(choice % oneof->field_count()) != f) continue;
    }
    const uint64_t v = salt * 131 + static_cast<uint64_t>(f->number()) * 7 + 1;
    const int count = f->is_repeated() ? kRepeatCount : 1;
    for (int k = 0; k < count; ++k) {
      const uint64_t x = v + static_cast<uint64_t>(k);
      const bool rep = f->is_repeated();
      switch (f->cpp_type()) {
        case FieldDescriptor::CPPTYPE_INT32: {
          const auto val = -static_cast<int32_t>(x % 100000) - 1;
          rep ? r->AddInt32(msg, f, val) : r->SetInt32(msg, f, val);
          break;
        }
        case FieldDescriptor::CPPTYPE_INT64: {
          const auto val = -static_cast<int64_t>(x) * 1000003 - 1;
          rep ? r->AddInt64(msg, f, val) : r->SetInt64(msg, f, val);
          break;
        }
        case FieldDescriptor::CPPTYPE_UINT32: {
          const auto val = static_cast<uint32_t>(x % 4000000000u) + 1;
          rep ? r->AddUInt32(msg, f, val) : r->SetUInt32(msg, f, val);
          break;
        }
        case FieldDescriptor::CPPTYPE_UINT64: {
          const uint64_t val = x * 0x9E3779B97F4A7C15ull | 1;
          rep ? r->AddUInt64(msg, f, val) : r->SetUInt64(msg, f, val);
          break;
        }
        case FieldDescriptor::CPPTYPE_DOUBLE: {
          const double val = 0.125 * static_cast<double>(x) + 1e-7;
          rep ? r->AddDouble(msg, f, val) : r->SetDouble(msg, f, val);
          break;
        }
        case FieldDescriptor::CPPTYPE_FLOAT: {
          const float val = 0.25F * static_cast<float>(x % 1000) + 0.5F;
          rep ? r->AddFloat(msg, f, val) : r->SetFloat(msg, f, val);
          break;
        }
        case FieldDescriptor::CPPTYPE_BOOL:
          rep ? r->AddBool(msg, f, (k % 2) == 0) : r->SetBool(msg, f, true);
          break;
        case FieldDescriptor::CPPTYPE_ENUM: {
          // The last value, so it differs from the default (first) one.
          const auto* e = f->enum_type();
          const int val = e->value(e->value_count() - 1)->number();
          rep ? r->AddEnumValue(msg, f, val) : r->SetEnumValue(msg, f, val);
          break;
        }
        case FieldDescriptor::CPPTYPE_STRING: {
          std::string val = f->type() == FieldDescriptor::TYPE_BYTES
                                ? std::string("\x00\xff\x7f", 3) + std::to_string(x)
                                : "s" + std::to_string(x);
          rep ? r->AddString(msg, f, val) : r->SetString(msg, f, std::move(val));
          break;
        }
        case FieldDescriptor::CPPTYPE_MESSAGE: {
          Message* sub = rep ? r->AddMessage(msg, f) : r->MutableMessage(msg, f);
          if (depth < kMaxDepth) FillAllFields(sub, choice, x, depth + 1);
          break;
        }
      }
    }
  }
}

/// Number of oneof alternatives to try so that each one is used once.
int ChoicesNeeded(const Descriptor* d, int depth = 0) {
  int n = 1;
  for (int i = 0; i < d->oneof_decl_count(); ++i) {
    if (!d->oneof_decl(i)->is_synthetic()) n = std::max(n, d->oneof_decl(i)->field_count());
  }
  if (depth < kMaxDepth) {
    for (int i = 0; i < d->field_count(); ++i) {
      if (d->field(i)->message_type() != nullptr) {
        n = std::max(n, ChoicesNeeded(d->field(i)->message_type(), depth + 1));
      }
    }
  }
  return n;
}

std::vector<const Descriptor*> MessagesOf(const FileDescriptor* file) {
  std::vector<const Descriptor*> out;
  for (int i = 0; i < file->message_type_count(); ++i) out.push_back(file->message_type(i));
  return out;
}

void ExpectRoundTrip(const Descriptor* d) {
  const Message* prototype = MessageFactory::generated_factory()->GetPrototype(d);
  ASSERT_NE(prototype, nullptr) << d->full_name();
  const int choices = ChoicesNeeded(d);
  for (int choice = 0; choice < choices; ++choice) {
    std::unique_ptr<Message> original(prototype->New());
    FillAllFields(original.get(), choice, 17, 0);

    // Every non-oneof field (and one alternative per oneof) is present.
    std::vector<const FieldDescriptor*> set;
    original->GetReflection()->ListFields(*original, &set);
    int expected = d->field_count();
    for (int i = 0; i < d->oneof_decl_count(); ++i) {
      if (!d->oneof_decl(i)->is_synthetic()) expected -= d->oneof_decl(i)->field_count() - 1;
    }
    EXPECT_EQ(static_cast<int>(set.size()), expected) << d->full_name() << " choice " << choice;

    std::string bytes;
    ASSERT_TRUE(original->SerializeToString(&bytes)) << d->full_name();
    std::unique_ptr<Message> parsed(prototype->New());
    ASSERT_TRUE(parsed->ParseFromString(bytes)) << d->full_name();
    std::string diff;
    MessageDifferencer differencer;
    differencer.ReportDifferencesToString(&diff);
    EXPECT_TRUE(differencer.Compare(*original, *parsed))
        << d->full_name() << " choice " << choice << ":\n" << diff;
  }
}

TEST(ProtoSchemaTest, EveryWireMessageRoundTripsWithAllFieldsSet) {
  const auto messages = MessagesOf(v1::ToolState::descriptor()->file());
  ASSERT_GE(messages.size(), 9U);
  for (const Descriptor* d : messages) ExpectRoundTrip(d);
}

TEST(ProtoSchemaTest, EverySceneMessageRoundTripsWithAllFieldsSet) {
  const auto messages = MessagesOf(v1::Scene::descriptor()->file());
  ASSERT_GE(messages.size(), 10U);
  for (const Descriptor* d : messages) ExpectRoundTrip(d);
}

TEST(ProtoSchemaTest, GeometryMessagesRoundTrip) {
  for (const Descriptor* d : MessagesOf(v1::Vec3::descriptor()->file())) ExpectRoundTrip(d);
}

TEST(ProtoSchemaTest, DifferencerSeesAChangedField) {
  // Guards the test itself: the comparison is not vacuous.
  v1::HapticModel a;
  FillAllFields(&a, 0, 3, 0);
  v1::HapticModel b = a;
  b.mutable_stiffness()->set_m(2, b.stiffness().m(2) + 1.0);
  EXPECT_FALSE(MessageDifferencer::Equals(a, b));
}

TEST(ProtoSchemaTest, RemovedDeltaEventsStayReserved) {
  // A retired field number or name must never be reused with another meaning:
  // old peers would misread it.
  const Descriptor* d = v1::MeshDelta::descriptor();
  EXPECT_EQ(d->FindFieldByNumber(7), nullptr);
  EXPECT_TRUE(d->IsReservedNumber(7));
  EXPECT_TRUE(d->IsReservedName("events"));
  const FileDescriptor* wire = d->file();
  for (const char* name : {"CutEvent", "VertexSplit", "NodeMove"}) {
    EXPECT_EQ(wire->FindMessageTypeByName(name), nullptr) << name;
  }
}

TEST(ProtoSchemaTest, WirePackageAndTypeNamesAreStable) {
  // Type names appear in error messages and logs; the package is part of the wire contract.
  EXPECT_EQ(v1::ToolState::descriptor()->full_name(), "cutsim.v1.ToolState");
  EXPECT_EQ(v1::MeshSnapshot::descriptor()->file()->package(), "cutsim.v1");
  EXPECT_EQ(v1::Scene::descriptor()->file()->syntax(), FileDescriptor::SYNTAX_PROTO3);
}

}  // namespace
}  // namespace cutsim

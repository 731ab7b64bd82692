#include "common/transport/report_json.h"

#include <memory>
#include <string_view>
#include <vector>

#include <google/protobuf/reflection.h>
#include <google/protobuf/util/json_util.h>

#include <fmt/format.h>

#include "common/core/log.h"

namespace cutsim::transport {
namespace {

namespace pb = google::protobuf;

/// Every string field of `msg` (nested messages included) as valid UTF-8.
void SanitizeStrings(pb::Message& msg) {
  const pb::Reflection* r = msg.GetReflection();
  std::vector<const pb::FieldDescriptor*> fields;
  r->ListFields(msg, &fields);
  for (const pb::FieldDescriptor* f : fields) {
    if (f->cpp_type() == pb::FieldDescriptor::CPPTYPE_STRING && f->type() == pb::FieldDescriptor::TYPE_STRING) {
      if (f->is_repeated()) {
        for (int i = 0; i < r->FieldSize(msg, f); ++i) {
          r->SetRepeatedString(&msg, f, i, ValidUtf8(r->GetRepeatedString(msg, f, i)));
        }
      } else {
        r->SetString(&msg, f, ValidUtf8(r->GetString(msg, f)));
      }
    } else if (f->cpp_type() == pb::FieldDescriptor::CPPTYPE_MESSAGE && !f->is_map()) {
      if (f->is_repeated()) {
        for (int i = 0; i < r->FieldSize(msg, f); ++i) SanitizeStrings(*r->MutableRepeatedMessage(&msg, f, i));
      } else {
        SanitizeStrings(*r->MutableMessage(&msg, f));
      }
    }
  }
}

}  // namespace

std::string ValidUtf8(std::string_view text) {
  std::string out;
  out.reserve(text.size());
  const auto* p = reinterpret_cast<const unsigned char*>(text.data());
  const size_t n = text.size();
  for (size_t i = 0; i < n;) {
    const unsigned char c = p[i];
    size_t len = 0;
    uint32_t cp = 0;
    if (c < 0x80) {
      len = 1;
      cp = c;
    } else if ((c & 0xE0) == 0xC0) {
      len = 2;
      cp = c & 0x1F;
    } else if ((c & 0xF0) == 0xE0) {
      len = 3;
      cp = c & 0x0F;
    } else if ((c & 0xF8) == 0xF0) {
      len = 4;
      cp = c & 0x07;
    }
    bool ok = len > 0 && i + len <= n;
    for (size_t k = 1; ok && k < len; ++k) {
      ok = (p[i + k] & 0xC0) == 0x80;
      cp = (cp << 6) | (p[i + k] & 0x3F);
    }
    // Overlong forms, surrogates and code points past U+10FFFF are invalid.
    static constexpr uint32_t kMinForLength[] = {0, 0, 0x80, 0x800, 0x10000};
    ok = ok && cp >= kMinForLength[len] && cp <= 0x10FFFF && !(cp >= 0xD800 && cp <= 0xDFFF);
    if (ok) {
      out.append(text.substr(i, len));
      i += len;
    } else {
      out.append("\xEF\xBF\xBD");  // U+FFFD REPLACEMENT CHARACTER
      ++i;
    }
  }
  return out;
}

std::string ReportJson(const google::protobuf::Message& report) {
  std::unique_ptr<pb::Message> clean(report.New());
  clean->CopyFrom(report);
  SanitizeStrings(*clean);
  google::protobuf::util::JsonPrintOptions options;
  options.add_whitespace = false;
  options.preserve_proto_field_names = true;
  options.always_print_primitive_fields = true;
  std::string json;
  const auto status = google::protobuf::util::MessageToJsonString(*clean, &json, options);
  if (!status.ok()) {
    Log().error("cannot print {} as JSON: {}", report.GetTypeName(), status.ToString());
    return "{}";
  }
  return json;
}

std::string HexHash(uint64_t hash) { return fmt::format("{:016x}", hash); }

}  // namespace cutsim::transport

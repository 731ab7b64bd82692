#include "common/transport/report_json.h"

#include <google/protobuf/util/json_util.h>

#include <fmt/format.h>

#include "common/core/log.h"

namespace cutsim::transport {

std::string ReportJson(const google::protobuf::Message& report) {
  google::protobuf::util::JsonPrintOptions options;
  options.add_whitespace = false;
  options.preserve_proto_field_names = true;
  options.always_print_primitive_fields = true;
  std::string json;
  const auto status = google::protobuf::util::MessageToJsonString(report, &json, options);
  if (!status.ok()) {
    Log().error("cannot print {} as JSON: {}", report.GetTypeName(), status.ToString());
    return "{}";
  }
  return json;
}

std::string HexHash(uint64_t hash) { return fmt::format("{:016x}", hash); }

}  // namespace cutsim::transport

#include "common/sim/checkpoint_part.h"

#include <cmath>

#include <fmt/format.h>

#include "common/core/error.h"

namespace cutsim::sim {

void Vec3ToProto(const Eigen::Vector3d& v, v1::Vec3* out) {
  out->set_x(v.x());
  out->set_y(v.y());
  out->set_z(v.z());
}

Eigen::Vector3d Vec3FromPart(const v1::Vec3& v, const std::string& source, const std::string& field) {
  const Eigen::Vector3d p(v.x(), v.y(), v.z());
  if (!p.allFinite()) FailPart(source, field, "non-finite coordinate");
  return p;
}

void CheckNodeOrNone(int64_t node, int32_t num_nodes, const std::string& source, const std::string& field) {
  if (node < -1 || node >= num_nodes) {
    FailPart(source, field, fmt::format("node {} out of range (the tissue has {} nodes)", node, num_nodes));
  }
}

void FailPart(const std::string& source, const std::string& field, const std::string& why) {
  ThrowInputError({.file = source, .field = field}, why);
}

}  // namespace cutsim::sim

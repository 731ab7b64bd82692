#pragma once
/// @file
/// Small helpers the stages share to write and check their checkpoint parts
/// (stage.h): vectors to and from their messages, and checks that throw
/// InputError naming the checkpoint file and the field.

#include <cstdint>
#include <string>

#include <Eigen/Core>

#include "cutsim/v1/geometry.pb.h"

namespace cutsim::sim {

void Vec3ToProto(const Eigen::Vector3d& v, v1::Vec3* out);
/// The vector of `v`; throws InputError naming `source` and `field` if a
/// coordinate is not finite.
[[nodiscard]] Eigen::Vector3d Vec3FromPart(const v1::Vec3& v, const std::string& source, const std::string& field);
/// Throws InputError naming `source` and `field` unless −1 ≤ `node` < `num_nodes`
/// (−1: none).
void CheckNodeOrNone(int64_t node, int32_t num_nodes, const std::string& source, const std::string& field);
/// Throws InputError naming `source` and `field`: `why`.
[[noreturn]] void FailPart(const std::string& source, const std::string& field, const std::string& why);

}  // namespace cutsim::sim

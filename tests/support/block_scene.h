#pragma once
// A coarse copy of scenes/block.pbtxt (4 × 2 × 1 cm, fixed base) cut by a
// scalpel dragged along y = 10 mm in 0.8 s: the cut scene of the checkpoint
// and journal tests.

#include <string>

namespace cutsim::support {

/// The scene text; `nx` cells along x (10 in the tests; another count makes
/// another mesh).
inline std::string BlockScene(const std::string& name, int nx = 10) {
  return R"pb(name: ")pb" + name + R"pb("
mesh { box { min { x: 0 y: 0 z: 0 } max { x: 0.04 y: 0.02 z: 0.01 } nx: )pb" + std::to_string(nx) + R"pb( ny: 5 nz: 2 } }
materials { name: "tissue" young_poisson { youngs_modulus: 50000 poisson_ratio: 0.4 } density: 1000 damping_psi: 0.5 }
boundary { plane { point { x: 0 y: 0 z: 0 } normal { x: 0 y: 0 z: 1 } } kind: KIND_FIXED }
gravity { z: -9.81 }
time_step { frame_dt: 0.01 threads: 1 }
tool {
  blade_length: 0.025
  keyframes { t: 0 tip { x: -0.003 y: 0.0101 z: -0.001 } blade_dir { z: 1 } }
  keyframes { t: 0.8 tip { x: 0.043 y: 0.0101 z: -0.001 } blade_dir { z: 1 } }
}
cutting { enabled: true alpha: 0.4 kappa: 1.0 zeta: 1.0 critical_stress: 10000 }
)pb";
}

}  // namespace cutsim::support

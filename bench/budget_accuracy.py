#!/usr/bin/python3
"""What the frame budget costs in accuracy, on one stroke.

Runs a scene headless twice on its own tool path, once with every step
converged to the scene's tolerance (--frame-budget 0) and once with the
real-time budget (--frame-budget B), and compares:
  - the force on the tool, sample by sample: RMS and peak difference
    relative to the converged run's peak force;
  - the cuts: cut steps made, and the final mesh (the same topology, and
    then the largest node position difference, m);
  - wall time, steps that hit the budget, the largest residual carried.
Prints one JSON object; exits 1 when a run fails, 2 on bad arguments.

  bench/budget_accuracy.py BIN_DIR OUT_DIR [SCENE] [BUDGET] [SECONDS]
"""
import json
import subprocess
import sys
from pathlib import Path

import meshio
import numpy as np


def run(bin_dir: Path, out: Path, scene: str, budget: float, seconds: float, tag: str) -> dict:
    report = out / f"budget_{tag}.report.json"
    vtu = out / f"budget_{tag}.vtu"
    summary = out / f"budget_{tag}.json"
    cmd = [str(bin_dir / "cutsim-server"), "--headless", "--scene", scene, "--no-progress",
           "--frame-budget", str(budget), "--session-report", str(report), "--out", str(vtu)]
    if seconds > 0:
        cmd += ["--duration", str(seconds)]
    with open(summary, "w") as f, open(out / f"budget_{tag}.log", "w") as log:
        rc = subprocess.run(cmd, stdout=f, stderr=log).returncode
    if rc != 0:
        raise RuntimeError(f"{' '.join(cmd)} exited {rc} (log: {out / f'budget_{tag}.log'})")
    return {"summary": json.loads(summary.read_text()), "report": json.loads(report.read_text()),
            "mesh": meshio.read(vtu)}


def main() -> int:
    if len(sys.argv) < 3:
        print(__doc__, file=sys.stderr)
        return 2
    bin_dir, out = Path(sys.argv[1]), Path(sys.argv[2])
    scene = sys.argv[3] if len(sys.argv) > 3 else "scenes/organ.pbtxt"
    budget = float(sys.argv[4]) if len(sys.argv) > 4 else 0.6
    seconds = float(sys.argv[5]) if len(sys.argv) > 5 else 0.0
    out.mkdir(parents=True, exist_ok=True)
    try:
        ref = run(bin_dir, out, scene, 0.0, seconds, "converged")
        bud = run(bin_dir, out, scene, budget, seconds, "budgeted")
    except (RuntimeError, OSError, ValueError) as e:
        print(json.dumps({"kind": "budget_accuracy", "error": str(e)}))
        return 1
    f_ref = np.asarray(ref["report"].get("force_n", []), dtype=float)
    f_bud = np.asarray(bud["report"].get("force_n", []), dtype=float)
    n = min(len(f_ref), len(f_bud))
    peak = float(np.max(np.abs(f_ref[:n]))) if n else 0.0
    diff = f_bud[:n] - f_ref[:n]
    same_topology = (ref["mesh"].points.shape == bud["mesh"].points.shape and
                     all(np.array_equal(a.data, b.data) for a, b in zip(ref["mesh"].cells, bud["mesh"].cells)))
    s_ref, s_bud = ref["summary"], bud["summary"]
    result = {
        "kind": "budget_accuracy", "scene": scene, "budget_fraction": budget,
        "force_samples": n, "peak_force_n": peak,
        "force_rms_rel": float(np.sqrt(np.mean(diff ** 2)) / peak) if n and peak > 0 else None,
        "force_max_rel": float(np.max(np.abs(diff)) / peak) if n and peak > 0 else None,
        "cuts": {"converged": s_ref.get("cuts"), "budgeted": s_bud.get("cuts")},
        "same_final_topology": bool(same_topology),
        "max_position_difference_m": float(np.max(np.linalg.norm(ref["mesh"].points - bud["mesh"].points, axis=1)))
        if same_topology else None,
        "wall_s": {"converged": s_ref.get("wall_time"), "budgeted": s_bud.get("wall_time")},
        "out_of_time_steps": s_bud.get("out_of_time_steps", 0),
        "over_budget_steps": s_bud.get("over_budget_steps", 0),
        "max_residual_carried_n": s_bud.get("max_residual_out_of_time", 0.0),
        "status": {"converged": s_ref.get("status"), "budgeted": s_bud.get("status")},
    }
    print(json.dumps(result))
    return 0 if s_ref.get("status") == "ok" and s_bud.get("status") == "ok" else 1


if __name__ == "__main__":
    sys.exit(main())

#!/usr/bin/python3
"""cutsim's static beam tip against the CalculiX references, per Poisson ratio.

For each ν of beam_nu_sweep.json, runs

  cutsim-server --headless --scene <beam.pbtxt with only ν changed>
                --until-rest --no-progress --threads 1 --out tip.vtu

and measures the tip as accuracy_bench does: the mean z-displacement of the
nodes on the free end face (rest x = L), read from the .vtu's displacement
field. Prints a Markdown table: ν, reference (tip_5x5_mean_m, the same nodes
on the exact field) ± uncertainty, cutsim, relative error.

With --element nodal_pressure the scene gets `element:
ELEMENT_NODAL_PRESSURE`, which needs the implicit integrator: the run is then
the static solve itself (`settle: true`, backward Euler, force tolerance
1e-9 N, one 10 ms frame) instead of --until-rest. --static does the same
for the linear element.

  compare_cutsim.py --server build/ci/bin/cutsim-server [--scene scenes/beam.pbtxt]
                    [--element linear|nodal_pressure] [--static]
"""

import argparse
import json
import os
import re
import subprocess
import sys
import tempfile

import meshio
import numpy as np

HERE = os.path.dirname(os.path.abspath(__file__))
ROOT = os.path.dirname(os.path.dirname(HERE))


def scene_with_poisson(text, poisson):
    new, count = re.subn(r"(poisson_ratio:\s*)[0-9.eE+-]+", lambda m: f"{m.group(1)}{poisson!r}", text)
    if count != 1:
        raise SystemExit(f"compare_cutsim: expected one poisson_ratio in the scene, found {count}")
    return new


def static_scene(text, element):
    """The scene solved statically at load (settle) with the given element."""
    new, count = re.subn(r"time_step\s*\{[^}]*\}",
                         "time_step { frame_dt: 0.01 integrator: INTEGRATOR_IMPLICIT "
                         "implicit { force_tolerance: 1e-9 } }", text)
    if count != 1:
        raise SystemExit(f"compare_cutsim: expected one time_step block in the scene, found {count}")
    kind = "ELEMENT_NODAL_PRESSURE" if element == "nodal_pressure" else "ELEMENT_LINEAR"
    return new + f"\nsettle: true\nelement: {kind}\n"


def cutsim_tip(server, scene_text, poisson, workdir, max_time, static, element):
    scene = os.path.join(workdir, f"beam_nu{poisson}.pbtxt")
    vtu = os.path.join(workdir, f"beam_nu{poisson}.vtu")
    text = scene_with_poisson(scene_text, poisson)
    if static:
        text = static_scene(text, element)
    with open(scene, "w", encoding="utf-8") as f:
        f.write(text)
    run = ["--duration", "0.01"] if static else ["--until-rest", "--max-time", str(max_time)]
    cmd = [server, "--headless", "--scene", scene, "--no-progress", "--threads", "1", *run, "--out", vtu]
    proc = subprocess.run(cmd, capture_output=True, text=True, timeout=1800)
    if proc.returncode != 0:
        raise SystemExit(f"compare_cutsim: {' '.join(cmd)} failed ({proc.returncode}):\n{proc.stderr[-2000:]}")
    summary = json.loads(proc.stdout.strip().splitlines()[-1])
    mesh = meshio.read(vtu)
    u = mesh.point_data["displacement"]  # #V×3
    rest = mesh.points - u
    tip = rest[:, 0] > rest[:, 0].max() - 1e-9
    return float(np.mean(u[tip, 2])), int(np.count_nonzero(tip)), len(mesh.cells_dict["tetra"]), summary


def main():
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--server", required=True, help="path of cutsim-server")
    parser.add_argument("--scene", default=os.path.join(ROOT, "scenes", "beam.pbtxt"))
    parser.add_argument("--reference", default=os.path.join(HERE, "beam_nu_sweep.json"))
    parser.add_argument("--max-time", type=float, default=20.0, help="cap on simulated seconds per run")
    parser.add_argument("--element", choices=["linear", "nodal_pressure"], default="linear")
    parser.add_argument("--static", action="store_true", help="solve statically at load (implied by nodal_pressure)")
    args = parser.parse_args()
    static = args.static or args.element == "nodal_pressure"
    with open(args.reference, encoding="ascii") as f:
        sweep = json.load(f)["sweep"]
    with open(args.scene, encoding="utf-8") as f:
        scene_text = f.read()
    print("| ν | CalculiX tip (mm) | cutsim tip (mm) | relative error | tets | at rest |")
    print("|---|---|---|---|---|---|")
    with tempfile.TemporaryDirectory(prefix="cutsim-compare-") as workdir:
        for entry in sweep:
            nu = entry["poisson"]
            tip, nodes, tets, summary = cutsim_tip(args.server, scene_text, nu, workdir, args.max_time, static,
                                                   args.element)
            ref, unc = entry["tip_5x5_mean_m"], entry["tip_5x5_uncertainty_m"]
            print(f"| {nu} | {ref * 1e3:.4f} ± {unc * 1e3:.4f} | {tip * 1e3:.4f} | {100 * (tip - ref) / ref:+.1f} % "
                  f"| {tets} | {summary.get('at_rest')} ({summary.get('sim_time', 0):.2f} s, {nodes} tip nodes) |",
                  flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())

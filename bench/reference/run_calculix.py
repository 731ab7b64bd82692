#!/usr/bin/python3
"""Independent CalculiX references for cutsim's accuracy bench.

Two problems, both St. Venant–Kirchhoff with geometric nonlinearity (CalculiX
*ELASTIC under *STEP, NLGEOM: Lagrangian (Green) strain, second
Piola–Kirchhoff stress, total Lagrangian), solved with quadratic elements at
several refinements:

  beam   scenes/beam.pbtxt: 100 × 20 × 20 mm cantilever, E = 1 MPa,
         ρ = 1000 kg/m³, gravity 9.81 m/s² along −z, every node of the face
         x = 0 fixed. Tip deflection = mean z-displacement of the free end
         face x = L, swept over ν ∈ {0.3, 0.45, 0.49, 0.499}.
  block  a 20 mm cube, E = 10 kPa, ν = 0.499, compressed by 20 % along z:
         "slip" (the brief's case: faces z = 0 and z = a held only along z,
         one corner pinned) and "bonded" (both faces held in all directions).
         Volume change and the force on the top face.

  run_calculix.py --out bench/reference/     regenerate the JSON files
  run_calculix.py --check bench/reference/   rerun the coarse levels and
                                             compare (exit 77: no ccx)
"""

import argparse
import json
import os
import sys
import time

import numpy as np

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
import calculix_deck as deck  # noqa: E402
import ccx_run  # noqa: E402

SKIP = 77
COMMAND = "bench/reference/run_calculix.py --out bench/reference/"

# ---- problem data -------------------------------------------------------------
BEAM = {"length_m": 0.1, "section_m": 0.02, "young_pa": 1.0e6, "density": 1000.0, "gravity": 9.81}
POISSON_SWEEP = (0.3, 0.45, 0.49, 0.499)
# Cells across the section; the length gets 5× as many. Even levels put the
# 5 × 5 tip points of cutsim's shipped 20 × 4 × 4 mesh on nodes.
BEAM_LEVELS = {"C3D10": (2, 4, 6), "C3D20R": (2, 4, 6, 8)}
BLOCK = {"size_m": 0.02, "young_pa": 1.0e4, "poisson": 0.499, "strain": 0.2}
BLOCK_LEVELS = {"slip": {"C3D20R": (2, 4), "C3D10": (2, 4)},
                "bonded": {"C3D20R": (4, 6, 8), "C3D10": (4, 6, 8)}}
# The quick rerun of --check: coarse enough for seconds, fine enough that a
# wrong deck (load, clamp, material) cannot match.
CHECK_RUNS = {"beam": [(0.3, "C3D20R", 4), (0.499, "C3D10", 4)], "block": [("slip", "C3D20R", 2),
                                                                           ("bonded", "C3D20R", 4)]}
CHECK_RTOL = 1e-4        # rerun against stored value (same deck, same ccx)
TIMOSHENKO_RTOL = 0.03   # stored ν = 0.3 tip against Timoshenko beam theory
ANALYTIC_RTOL = 1e-4     # slip block against the closed-form homogeneous solution
# Headers of the CSV summaries read by reference_data.h.
BEAM_CSV_HEADER = "poisson,element,tip_m,tip_uncertainty_m,tip_5x5_mean_m,tip_5x5_uncertainty_m"
BLOCK_CSV_HEADER = ("variant,element,volume_change,volume_change_uncertainty,top_force_z_n,"
                    "top_force_z_uncertainty_n")


# ---- the beam -----------------------------------------------------------------
def beam_mesh(element, level):
    size = (BEAM["length_m"], BEAM["section_m"], BEAM["section_m"])
    return deck.QuadraticBoxMesh(size, (5 * level, level, level), element)


def run_beam(ccx, poisson, element, level, timeout_s):
    """Solves the cantilever on (5·level, level, level) cells; the tip
    deflection by the definitions of beam_document's tip_definition."""
    mesh = beam_mesh(element, level)
    length, section = BEAM["length_m"], BEAM["section_m"]
    fixed = mesh.nodes_where(lambda p: p[0] < 1e-12)
    tip = mesh.nodes_where(lambda p: p[0] > length - 1e-12)
    material = {"young_pa": BEAM["young_pa"], "poisson": poisson, "density": BEAM["density"]}
    grav = f"ELALL, GRAV, {BEAM['gravity']:.17g}, 0., 0., -1."

    def write(path):
        deck.write_deck(path, mesh, material, {"NFIX": fixed, "NTIP": tip}, [("NFIX", 1, 3, 0.0)], [grav],
                        [("NSET=NTIP", "U")])

    blocks, wall = ccx_run.run(ccx, write, timeout_s)
    uz = {nid: u[2] for nid, u in blocks[("U", "NTIP")].items()}
    corners = set(mesh.corner_ids())
    grid = [nid for nid in tip if _on_grid(mesh.nodes[nid], section / 4)]
    return {
        "element": element, "cells": list(mesh.n), "nodes": len(mesh.nodes), "elements": len(mesh.elements),
        "tip_m": deck.face_mean(mesh, mesh.faces_on_plane(0, length), uz),
        "tip_corner_node_mean_m": float(np.mean([uz[n] for n in tip if n in corners])),
        "tip_5x5_mean_m": float(np.mean([uz[n] for n in grid])) if len(grid) == 25 else None,
        "wall_s": round(wall, 2),
    }


def _on_grid(p, spacing):
    return all(abs(v / spacing - round(v / spacing)) < 1e-9 for v in p[1:])


def beam_theory(poisson):
    """Euler–Bernoulli and Timoshenko (shear factor 5/6) tips, m, signed."""
    a, length, young = BEAM["section_m"], BEAM["length_m"], BEAM["young_pa"]
    q = BEAM["density"] * BEAM["gravity"] * a * a
    inertia = a ** 4 / 12.0
    shear = young / (2.0 * (1.0 + poisson))
    eb = -q * length ** 4 / (8.0 * young * inertia)
    return eb, eb - q * length ** 2 / (2.0 * (5.0 / 6.0) * shear * a * a)


def converged(runs, key="tip_m"):
    """Finest value of a refinement sequence and |finest − previous|."""
    values = [r[key] for r in runs if r.get(key) is not None]
    return values[-1], abs(values[-1] - values[-2])


class RunCache:
    """Results of finished ccx runs kept in a JSON file (--cache), so an
    interrupted --out resumes where it stopped. Without a path: no cache."""

    def __init__(self, path):
        self.path = path
        self.runs = {}
        if path and os.path.exists(path):
            with open(path, encoding="ascii") as f:
                self.runs = json.load(f)

    def get(self, key, compute):
        if key not in self.runs:
            self.runs[key] = compute()
            if self.path:
                write_json(self.path, self.runs)
        return self.runs[key]


def beam_sweep(ccx, timeout_s, log, cache):
    sweep = []
    for poisson in POISSON_SWEEP:
        by_element = {}
        for element, levels in BEAM_LEVELS.items():
            by_element[element] = []
            for level in levels:
                r = cache.get(f"beam {poisson} {element} {level}",
                              lambda: run_beam(ccx, poisson, element, level, timeout_s))
                log(f"beam nu={poisson} {element} cells={r['cells']}: tip {r['tip_m'] * 1e3:.5f} mm "
                    f"({r['wall_s']} s)")
                by_element[element].append(r)
        sweep.append(summarise_beam(poisson, by_element))
    return sweep


def richardson(hs, qs):
    """Extrapolation q(h) = q∞ + C·h^p through the last three (h, q), with the
    observed order p; (q∞, p), or (None, None) when the values do not
    converge monotonically."""
    (h1, h2, h3), (q1, q2, q3) = hs[-3:], qs[-3:]
    ratio = (q1 - q2) / (q2 - q3) if q2 != q3 else float("inf")
    f = lambda p: (h1 ** p - h2 ** p) / (h2 ** p - h3 ** p) - ratio  # noqa: E731
    lo, hi = 0.2, 8.0
    if not ratio > 0 or f(lo) * f(hi) > 0:
        return None, None
    for _ in range(200):
        mid = 0.5 * (lo + hi)
        lo, hi = (mid, hi) if f(lo) * f(mid) > 0 else (lo, mid)
    p = 0.5 * (lo + hi)
    return q3 - (q2 - q3) * h3 ** p / (h2 ** p - h3 ** p), p


def summarise_beam(poisson, by_element):
    """Picks the element family with the smaller last change as the reference;
    the other family's finest value is the cross-check. The uncertainty is
    the larger of the last change and the distance to the Richardson
    extrapolation: the clamped edges are singular, so the observed order is
    below 2 and the last change alone understates the remaining error."""
    best = min(by_element, key=lambda e: converged(by_element[e])[1])
    runs = by_element[best]
    tip, last_change = converged(runs)
    extrapolated, order = richardson([1.0 / r["cells"][1] for r in runs], [r["tip_m"] for r in runs])
    uncertainty = max(last_change, abs(extrapolated - tip) if extrapolated is not None else 0.0)
    tip_5x5 = next(r["tip_5x5_mean_m"] for r in reversed(runs) if r["tip_5x5_mean_m"] is not None)
    others = {e: rs[-1]["tip_m"] for e, rs in by_element.items() if e != best}
    return {"poisson": poisson, "reference_element": best, "tip_m": tip, "tip_uncertainty_m": uncertainty,
            "tip_last_change_m": last_change, "tip_richardson_m": extrapolated, "richardson_order": order,
            "tip_5x5_mean_m": tip_5x5, "tip_5x5_uncertainty_m": uncertainty + abs(tip_5x5 - tip),
            "finest_other_elements_tip_m": others, "runs": [r for rs in by_element.values() for r in rs]}


# ---- the compressed block -----------------------------------------------------
def block_analytic():
    """Homogeneous uniaxial compression of a StVK cube (the slip case): lateral
    Green strain −ν·E_zz, so J = λ_x²·λ_z and the top force is λ_z·E·E_zz·A."""
    a, young, nu, strain = BLOCK["size_m"], BLOCK["young_pa"], BLOCK["poisson"], BLOCK["strain"]
    stretch_z = 1.0 - strain
    green_z = 0.5 * (stretch_z ** 2 - 1.0)
    stretch_x2 = 1.0 + 2.0 * (-nu * green_z)
    return {"volume_ratio": stretch_x2 * stretch_z, "top_force_z_n": stretch_z * young * green_z * a * a}


def run_block(ccx, variant, element, level, timeout_s):
    """Compresses the cube on level³ cells ("slip" or "bonded" faces); the
    volume ratio V/V₀ and the z force on the top face."""
    a = BLOCK["size_m"]
    mesh = deck.QuadraticBoxMesh((a, a, a), (level, level, level), element)
    bottom = mesh.nodes_where(lambda p: p[2] < 1e-12)
    top = mesh.nodes_where(lambda p: p[2] > a - 1e-12)
    every = sorted(mesh.nodes)
    if variant == "slip":
        origin = mesh.nodes_where(lambda p: np.linalg.norm(p) < 1e-12)[0]
        x_axis = mesh.nodes_where(lambda p: abs(p[0] - a) < 1e-12 and abs(p[1]) + abs(p[2]) < 1e-12)[0]
        boundary = [("NBOT", 3, 3, 0.0), (origin, 1, 2, 0.0), (x_axis, 2, 2, 0.0), ("NTOP", 3, 3, -BLOCK["strain"] * a)]
    else:
        boundary = [("NBOT", 1, 3, 0.0), ("NTOP", 1, 2, 0.0), ("NTOP", 3, 3, -BLOCK["strain"] * a)]
    material = {"young_pa": BLOCK["young_pa"], "poisson": BLOCK["poisson"]}

    def write(path):
        deck.write_deck(path, mesh, material, {"NBOT": bottom, "NTOP": top, "NALL": every}, boundary, [],
                        [("NSET=NALL", "U"), ("NSET=NTOP, TOTALS=ONLY", "RF")], increment=0.1)

    blocks, wall = ccx_run.run(ccx, write, timeout_s)
    u = blocks[("U", "NALL")]
    deformed = {nid: p + np.array(u[nid]) for nid, p in mesh.nodes.items()}
    volume = deck.enclosed_volume(mesh, deformed)
    return {"element": element, "cells": list(mesh.n), "nodes": len(mesh.nodes), "elements": len(mesh.elements),
            "volume_ratio": volume / a ** 3, "top_force_z_n": blocks[("RF_TOTAL", "NTOP")][2],
            "wall_s": round(wall, 2)}


def block_study(ccx, timeout_s, log, cache):
    variants = []
    for variant, families in BLOCK_LEVELS.items():
        by_element = {}
        for element, levels in families.items():
            by_element[element] = []
            for level in levels:
                r = cache.get(f"block {variant} {element} {level}",
                              lambda: run_block(ccx, variant, element, level, timeout_s))
                log(f"block {variant} {element} cells={r['cells']}: J {r['volume_ratio']:.6f}, "
                    f"Fz {r['top_force_z_n']:.6f} N ({r['wall_s']} s)")
                by_element[element].append(r)
        best = min(by_element, key=lambda e: converged(by_element[e], "top_force_z_n")[1])
        ratio, d_ratio = converged(by_element[best], "volume_ratio")
        force, d_force = converged(by_element[best], "top_force_z_n")
        variants.append({"variant": variant, "reference_element": best, "volume_change": ratio - 1.0,
                         "volume_change_uncertainty": d_ratio, "top_force_z_n": force,
                         "top_force_z_uncertainty_n": d_force,
                         "runs": [r for runs in by_element.values() for r in runs]})
    return variants


# ---- the JSON documents ---------------------------------------------------------
MATERIAL_NOTE = ("CalculiX *ELASTIC (isotropic) under *STEP, NLGEOM: Lagrangian (Green) strain and second "
                 "Piola-Kirchhoff stress, total Lagrangian: St. Venant-Kirchhoff, as cutsim's tets")


def beam_document(ccx, sweep):
    eb, timo = beam_theory(0.3)
    return {
        "problem": "scenes/beam.pbtxt cantilever: x in [0, 0.1], y, z in [0, 0.02] m; every node on x = 0 fixed; "
                   "gravity 9.81 m/s^2 along -z on density 1000 kg/m^3; static equilibrium",
        "units": {"length": "m", "force": "N", "stress": "Pa"},
        "material": {"young_pa": BEAM["young_pa"], "density_kg_m3": BEAM["density"], "model": MATERIAL_NOTE},
        "tip_definition": "tip_m: area mean of u_z over the end face x = 0.1 m, integrated with the quadratic "
                          "shape functions; tip_5x5_mean_m: plain mean of u_z at the 5 x 5 node positions of "
                          "cutsim's 20 x 4 x 4 mesh (accuracy_bench's definition on that mesh)",
        "convergence": "each element family refined with cells (5n, n, n); the reference is the finest run of "
                       "the family with the smaller last change; tip_uncertainty_m = max(|finest - previous|, "
                       "|tip_richardson_m - finest|), tip_richardson_m extrapolating that family's last three runs "
                       "with their observed order; tip_5x5_uncertainty_m adds |tip_5x5_mean_m - tip_m|",
        "theory_nu_0.3": {"euler_bernoulli_tip_m": eb, "timoshenko_tip_m": timo, "shear_factor": 5.0 / 6.0},
        "ccx_version": ccx_run.ccx_version(ccx), "command": COMMAND,
        "sweep": sweep,
    }


def block_document(ccx, variants):
    return {
        "problem": "cube [0, 0.02]^3 m compressed to 80 % of its height along z by a displacement of the top "
                   "face z = 0.02 m; slip: faces z = 0 and z = a held along z only, node (0,0,0) held in x, y "
                   "and node (a,0,0) in y; bonded: both faces held in x, y, z",
        "units": {"length": "m", "force": "N", "stress": "Pa"},
        "material": {"young_pa": BLOCK["young_pa"], "poisson": BLOCK["poisson"], "model": MATERIAL_NOTE},
        "definitions": "volume_change = V/V0 - 1 (V from the deformed quadratic boundary); top_force_z_n = z "
                       "reaction summed over the top face nodes (negative: pushes down)",
        "analytic_slip": block_analytic(),
        "ccx_version": ccx_run.ccx_version(ccx), "command": COMMAND,
        "variants": variants,
    }


def write_json(path, document):
    with open(path, "w", encoding="ascii") as f:
        json.dump(document, f, indent=1)
        f.write("\n")


def write_csv_summaries(out_dir):
    """The converged values of the JSON files as CSV, for reference_data.h."""
    beam, block = _load(out_dir, "beam_nu_sweep.json"), _load(out_dir, "compressed_block.json")
    comment = f"# CalculiX {beam['ccx_version']} references; full data in the .json beside; written by {COMMAND}\n"
    beam_keys = ("poisson", "reference_element", "tip_m", "tip_uncertainty_m", "tip_5x5_mean_m",
                 "tip_5x5_uncertainty_m")
    block_keys = ("variant", "reference_element", "volume_change", "volume_change_uncertainty", "top_force_z_n",
                  "top_force_z_uncertainty_n")
    for name, header, keys, rows in (
            ("beam_nu_sweep.csv", BEAM_CSV_HEADER, beam_keys, beam["sweep"]),
            ("compressed_block.csv", BLOCK_CSV_HEADER, block_keys, block["variants"])):
        with open(os.path.join(out_dir, name), "w", encoding="ascii") as f:
            f.write(comment + header + "\n")
            for row in rows:
                f.write(",".join(v if isinstance(v, str) else repr(v) for v in (row[k] for k in keys)) + "\n")


def generate(ccx, out_dir, timeout_s, log, cache):
    start = time.monotonic()
    sweep = beam_sweep(ccx, timeout_s, log, cache)
    write_json(os.path.join(out_dir, "beam_nu_sweep.json"), beam_document(ccx, sweep))
    variants = block_study(ccx, timeout_s, log, cache)
    write_json(os.path.join(out_dir, "compressed_block.json"), block_document(ccx, variants))
    write_csv_summaries(out_dir)
    log(f"wrote {out_dir} in {time.monotonic() - start:.0f} s")
    failures = check_stored(out_dir)
    for failure in failures:
        log("FAIL " + failure)
    return 1 if failures else 0


# ---- the check ------------------------------------------------------------------
def _load(directory, name):
    path = os.path.join(directory, name)
    try:
        with open(path, encoding="ascii") as f:
            return json.load(f)
    except (OSError, ValueError) as e:
        raise SystemExit(f"run_calculix: cannot read {path}: {e}")


def _stored_run(runs, element, cells, where):
    for r in runs:
        if r["element"] == element and r["cells"] == cells:
            return r
    raise SystemExit(f"run_calculix: {where}: no stored run {element} {cells}")


def _close(failures, what, got, want, rtol):
    if not abs(got - want) <= rtol * abs(want):
        failures.append(f"{what}: {got:.9g} vs {want:.9g} (rtol {rtol:g})")


def check_stored(directory):
    """Properties of the stored documents that need no ccx."""
    beam, block = _load(directory, "beam_nu_sweep.json"), _load(directory, "compressed_block.json")
    failures = []
    for entry in beam["sweep"]:
        nu = entry["poisson"]
        if not entry["tip_uncertainty_m"] <= 0.01 * abs(entry["tip_m"]):
            failures.append(f"beam nu={nu}: not converged to 1 % ({entry['tip_uncertainty_m']:.3g} m)")
        for element, other in entry["finest_other_elements_tip_m"].items():
            _close(failures, f"beam nu={nu}: {element} against {entry['reference_element']}", other,
                   entry["tip_m"], 0.02)
    at_03 = next(e for e in beam["sweep"] if e["poisson"] == 0.3)
    _close(failures, "beam nu=0.3 tip against Timoshenko", at_03["tip_m"],
           beam["theory_nu_0.3"]["timoshenko_tip_m"], TIMOSHENKO_RTOL)
    analytic = block["analytic_slip"]
    slip = next(v for v in block["variants"] if v["variant"] == "slip")
    _close(failures, "slip block volume ratio against closed form", 1.0 + slip["volume_change"],
           analytic["volume_ratio"], ANALYTIC_RTOL)
    _close(failures, "slip block force against closed form", slip["top_force_z_n"], analytic["top_force_z_n"],
           ANALYTIC_RTOL)
    return failures


def check(ccx, directory, timeout_s, log):
    failures = check_stored(directory)
    beam, block = _load(directory, "beam_nu_sweep.json"), _load(directory, "compressed_block.json")
    for nu, element, level in CHECK_RUNS["beam"]:
        entry = next(e for e in beam["sweep"] if e["poisson"] == nu)
        r = run_beam(ccx, nu, element, level, timeout_s)
        stored = _stored_run(entry["runs"], element, r["cells"], f"beam nu={nu}")
        _close(failures, f"beam nu={nu} {element} {r['cells']} tip", r["tip_m"], stored["tip_m"], CHECK_RTOL)
        log(f"beam nu={nu} {element} {r['cells']}: tip {r['tip_m']:.9g} m, stored {stored['tip_m']:.9g} m")
    for variant, element, level in CHECK_RUNS["block"]:
        entry = next(v for v in block["variants"] if v["variant"] == variant)
        r = run_block(ccx, variant, element, level, timeout_s)
        stored = _stored_run(entry["runs"], element, r["cells"], f"block {variant}")
        for key in ("volume_ratio", "top_force_z_n"):
            _close(failures, f"block {variant} {element} {r['cells']} {key}", r[key], stored[key], CHECK_RTOL)
        log(f"block {variant} {element} {r['cells']}: J {r['volume_ratio']:.9g}, Fz {r['top_force_z_n']:.9g} N")
    for failure in failures:
        log("FAIL " + failure)
    log("reference check: " + ("FAILED" if failures else "passed"))
    return 1 if failures else 0


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    mode = parser.add_mutually_exclusive_group(required=True)
    mode.add_argument("--out", metavar="DIR", help="run every refinement and write the JSON files into DIR")
    mode.add_argument("--check", metavar="DIR", help="rerun the coarse levels against the JSON files in DIR")
    parser.add_argument("--ccx", help="path of the ccx binary (default: ccx on PATH)")
    parser.add_argument("--timeout", type=float, default=600.0, help="wall-time limit of one ccx run, s")
    parser.add_argument("--cache", metavar="FILE", help="with --out: keep finished runs here and reuse them")
    args = parser.parse_args(argv)

    def log(message):
        print(message, flush=True)

    ccx = ccx_run.find_ccx(args.ccx)
    if ccx is None:
        where = args.ccx or "ccx on PATH"
        print(f"run_calculix: {where} not found: install calculix-ccx (deploy/install-deps.sh --bench)",
              file=sys.stderr)
        return SKIP if args.check else 2
    try:
        if args.out:
            os.makedirs(args.out, exist_ok=True)
            return generate(ccx, args.out, args.timeout, log, RunCache(args.cache))
        return check(ccx, args.check, args.timeout, log)
    except ccx_run.CcxError as e:
        print(f"run_calculix: {e}", file=sys.stderr)
        return 1


if __name__ == "__main__":
    sys.exit(main())

#!/usr/bin/python3
"""Plots of deploy/bench.sh's JSON results (matplotlib, PNG) and a Markdown
summary table (summary.md) in the same folder.

    /usr/bin/python3 bench/plot.py out/bench
"""
import json
import os
import re
import sys

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402


def load(path):
    with open(path) as f:
        return json.load(f)


def medians(bench):
    """name → benchmark entry (median aggregate if present, else the run)."""
    out = {}
    for b in bench["benchmarks"]:
        if b.get("run_type") == "aggregate" and b.get("aggregate_name") != "median":
            continue
        name = b.get("run_name", b["name"])
        out[name] = b
    return out


def main(folder):
    bench = medians(load(os.path.join(folder, "fem_bench.json")))
    lines = []
    triad = {int(b["threads"]): b["bytes_per_s"] for n, b in bench.items() if n.startswith("BM_Triad")}
    lines.append("## STREAM triad (same run)\n")
    lines.append("| threads | GB/s |\n|---|---|")
    for t in sorted(triad):
        lines.append(f"| {t} | {triad[t] / 1e9:.1f} |")

    # Throughput: BM_<Kind><T>/size/threads/damped
    pat = re.compile(r"BM_(Force|Step)<(double|float)>/(\d)/(\d)/(\d)")
    rows = []
    for name, b in bench.items():
        m = pat.match(name)
        if not m:
            continue
        kind, scalar, size, threads, damped = m.groups()
        rows.append(dict(kind=kind, scalar=scalar, tets=b["tets"], threads=int(threads), damped=int(damped),
                         rate=b["tet_steps_per_s"], bytes_per_tet=b.get("bytes_per_tet", 0)))
    fig, axes = plt.subplots(1, 2, figsize=(12, 4.5), sharey=True)
    for ax, kind in zip(axes, ["Force", "Step"]):
        for scalar in ["double", "float"]:
            for threads in [1, 2]:
                for damped in [0, 1]:
                    pts = sorted((r["tets"], r["rate"]) for r in rows if r["kind"] == kind and r["scalar"] == scalar
                                 and r["threads"] == threads and r["damped"] == damped)
                    if not pts:
                        continue
                    ax.plot([p[0] for p in pts], [p[1] / 1e6 for p in pts],
                            marker="o" if scalar == "double" else "s",
                            linestyle="-" if damped else "--",
                            label=f"{scalar}, {threads} thr, {'damped' if damped else 'undamped'}")
        ax.axhline(100, color="k", linewidth=0.8, linestyle=":")
        ax.text(1.2e3, 103, "target 100M (double, damped, 2 thr, 100k)", fontsize=7)
        ax.set_xscale("log")
        ax.set_xlabel("tets")
        ax.set_title("force pass" if kind == "Force" else "full step")
        ax.grid(True, which="both", alpha=0.3)
    axes[0].set_ylabel("million tet-steps / s")
    axes[1].legend(fontsize=7)
    fig.tight_layout()
    fig.savefig(os.path.join(folder, "throughput.png"), dpi=120)

    lines.append("\n## Throughput, million tet-steps/s (medians)\n")
    lines.append("| kind | scalar | tets | threads | damping | Mtet-steps/s | roofline fraction |")
    lines.append("|---|---|---|---|---|---|---|")
    for r in sorted(rows, key=lambda r: (r["kind"], r["scalar"], r["tets"], r["threads"], r["damped"])):
        roof = ""
        if r["kind"] == "Force" and r["bytes_per_tet"] and r["threads"] in triad:
            roof = f"{r['rate'] * r['bytes_per_tet'] / triad[r['threads']]:.2f}"
        lines.append(f"| {r['kind']} | {r['scalar']} | {int(r['tets'])} | {r['threads']} | "
                     f"{'on' if r['damped'] else 'off'} | {r['rate'] / 1e6:.1f} | {roof} |")

    # Skip table.
    skip = {(int(b["case"]), int(b["work_on"])): b["tet_steps_per_s"] for n, b in bench.items()
            if n.startswith("BM_Skip")}
    names = {0: "damping stress (ψ = φ = 0), force pass", 1: "gravity work (gravity off), full step",
             2: "fixed nodes not integrated (half the nodes fixed vs none), full step"}
    lines.append("\n## Skip table (~100k tets, 1 thread, double)\n")
    lines.append("| skip | skipped Mtet-steps/s | forced on Mtet-steps/s | saving |")
    lines.append("|---|---|---|---|")
    labels, saves = [], []
    for c in sorted(names):
        if (c, 0) in skip and (c, 1) in skip:
            s = 1 - skip[(c, 1)] / skip[(c, 0)]
            lines.append(f"| {names[c]} | {skip[(c, 0)] / 1e6:.1f} | {skip[(c, 1)] / 1e6:.1f} | {100 * s:.0f}% |")
            labels.append(names[c].split(" (")[0])
            saves.append(100 * s)
    if labels:
        fig, ax = plt.subplots(figsize=(7, 3))
        ax.barh(labels, saves)
        ax.set_xlabel("time saved by the skip, %")
        fig.tight_layout()
        fig.savefig(os.path.join(folder, "skips.png"), dpi=120)

    organ_path = os.path.join(folder, "organ_mesh.json")
    if os.path.exists(organ_path):
        o = load(organ_path)
        lines.append("\n## Organ mesh: gmsh output vs cleaned\n")
        lines.append("| mesh | tets | min mean ratio | tets < 0.3 | min altitude mm | median/min altitude | "
                     "stable-step bound µs |")
        lines.append("|---|---|---|---|---|---|---|")
        for k in ["gmsh", "cleaned"]:
            m = o[k]
            lines.append(f"| {k} | {m['tets']} | {m['min_mean_ratio']:.3f} | {m['tets_below_0_3']} | "
                         f"{1e3 * m['min_altitude_m']:.3f} | {m['altitude_ratio']:.1f} | "
                         f"{1e6 * m['stable_dt_bound_s']:.2f} |")
    with open(os.path.join(folder, "summary.md"), "w") as f:
        f.write("\n".join(lines) + "\n")
    print("\n".join(lines))


if __name__ == "__main__":
    main(sys.argv[1] if len(sys.argv) > 1 else "out/bench")

#!/usr/bin/python3
"""Plots of deploy/bench.sh's JSON results (matplotlib, PNG) and a Markdown
summary table (summary.md) in the same folder.

    /usr/bin/python3 bench/plot.py out/bench
    /usr/bin/python3 bench/plot.py out/bench link   # the link fidelity plots only
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
    # Session-level skips (skip_bench): the same scene per row, work off vs on.
    session_path = os.path.join(folder, "skip.json")
    if os.path.exists(session_path):
        lines.append("\n## Skip table, session level (skip_bench; µs per physics frame, medians)\n")
        lines.append("| skip | scene | skipped | µs/frame | forced on | µs/frame | saving |")
        lines.append("|---|---|---|---|---|---|---|")
        for r in load(session_path)["rows"]:
            lines.append(f"| {r['skip']} | {r['scene']} | {r['skipped']} | {r['skipped_us_per_frame']:.1f} | "
                         f"{r['forced_on']} | {r['forced_on_us_per_frame']:.1f} | {100 * r['saving']:.0f}% |")
            labels.append(f"{r['skip']} ({r['scene']}: {r['forced_on']})")
            saves.append(100 * r["saving"])
    if labels:
        fig, ax = plt.subplots(figsize=(9, 0.4 * len(labels) + 1.2))
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


def pareto_front(points):
    """Indices of the non-dominated (wall, error) points: no other point is
    both faster and at least as accurate."""
    order = sorted(range(len(points)), key=lambda i: (points[i][0], points[i][1]))
    front, best = [], float("inf")
    for i in order:
        if points[i][1] < best:
            front.append(i)
            best = points[i][1]
    return front


def plot_accuracy(folder):
    """accuracy_bench: error vs wall time with the Pareto frontier,
    the beam convergence against beam theory, the buffer-model rate panel, and
    the recommended settings per target error (appended to summary.md)."""
    path = os.path.join(folder, "accuracy.json")
    if not os.path.exists(path):
        return
    acc = load(path)
    beam = acc["beam"]
    runs = [r for r in beam["runs"] if r["ok"]]
    cut = [r for r in acc["cut"]["runs"] if r["tag"] != "reference" and r["status"] == "ok"]
    block = acc["cut"]["block_length_m"]
    panels = [
        ("static: tip deflection", runs, "static_wall_s", lambda r: r["tip_rel_error"]),
        ("dynamic: first bending frequency", runs, "dynamic_wall_s", lambda r: r["frequency_rel_error"]),
        ("dynamic: amplitude decay rate", runs, "dynamic_wall_s", lambda r: r["decay_rel_error"]),
        ("cut: mean surface distance / block length", cut, "wall_s", lambda r: r["mean_distance_m"] / block),
    ]
    markers = {"default": "o", "dt0.5": "v", "dt1.0": "^", "float": "s", "explicit": "D", "float,dt1.0": "P"}

    def label(r):
        size = f"L{r['level']}" if "level" in r else f"x{r['scale']:g}"
        return f"{size} {r['tag']}"

    lines = ["\n## Run time against error (accuracy_bench; errors vs the converged reference)\n"]
    fig, axes = plt.subplots(2, 2, figsize=(12, 9))
    for ax, (title, rs, wall_key, err) in zip(axes.flat, panels):
        # A run on the reference's own finest mesh has no meaningful error when
        # the extrapolation was not valid (the reference is then that mesh):
        # left out of the plot and of the frontier.
        ref_key = {"static: tip deflection": "tip_m", "dynamic: first bending frequency": "frequency_hz",
                   "dynamic: amplitude decay rate": "decay_rate_per_s"}.get(title)
        finest = max((r.get("level", 0) for r in rs), default=0)
        self_ref = bool(ref_key) and not beam["reference"][ref_key]["valid"]
        if self_ref:
            rs = [r for r in rs if r.get("level") != finest]
        pts = [(max(r[wall_key], 1e-4), max(err(r), 1e-7)) for r in rs]
        if not pts:
            ax.set_title(title + " (no runs)", fontsize=10)
            ax.axis("off")
            continue
        for tag in markers:
            sel = [(p, r) for p, r in zip(pts, rs) if r["tag"] == tag]
            if sel:
                ax.scatter([p[0] for p, _ in sel], [p[1] for p, _ in sel], marker=markers[tag], label=tag, s=30)
        front = pareto_front(pts)
        ax.plot([pts[i][0] for i in front], [pts[i][1] for i in front], "k-", lw=1, label="Pareto frontier")
        for i in front:
            ax.annotate(label(rs[i]), pts[i], fontsize=6, xytext=(3, 3), textcoords="offset points")
        for target in (0.1, 0.01, 0.001):
            ax.axhline(target, color="grey", lw=0.6, ls=":")
        ax.set_xscale("log")
        ax.set_yscale("log")
        ax.set_xlabel("wall time, s (1 thread)")
        ax.set_ylabel("relative error")
        ax.set_title(title, fontsize=10)
        ax.grid(True, which="both", alpha=0.3)
        ax.legend(fontsize=6)
        lines.append(f"**{title}** — cheapest run on the frontier per target:\n")
        if self_ref:
            lines.append(f"(reference not extrapolated — differences do not shrink monotonically; the finest mesh "
                         f"L{finest} is the reference and its own runs are excluded)\n")
        lines.append("| target | setting | tets | wall s | error |\n|---|---|---|---|---|")
        usable = range(len(rs))
        for target in (0.1, 0.01, 0.001):
            ok = [i for i in usable if pts[i][1] <= target]
            if ok:
                i = min(ok, key=lambda i: pts[i][0])
                r = rs[i]
                setting = f"{label(r)}, {r['precision']}, safety {r['safety']:g}"
                if "viscous" in r:
                    setting += f", viscous {r['viscous']}"
                lines.append(f"| {100 * target:g}% | {setting} | {r['tets']} | {pts[i][0]:.3g} | {pts[i][1]:.2e} |")
            else:
                lines.append(f"| {100 * target:g}% | not reached by any run | | | |")
        lines.append("")
    fig.tight_layout()
    fig.savefig(os.path.join(folder, "accuracy_pareto.png"), dpi=120)

    # Convergence of the default runs against the reference and beam theory.
    ref = beam["reference"]
    theory = beam["theory"]
    default = sorted((r for r in runs if r["tag"] == "default"), key=lambda r: r["level"])
    if default:
        fig, axes = plt.subplots(1, 3, figsize=(14, 4))
        h = [1e3 * beam["geometry"]["section_m"] / r["level"] for r in default]
        axes[0].plot(h, [-1e3 * r["tip_m"] for r in default], "o-", label="FEM (default settings)")
        axes[0].axhline(-1e3 * ref["tip_m"]["value"], color="k", ls="--", label="Richardson reference")
        axes[0].axhline(-1e3 * theory["euler_bernoulli_tip_m"], color="C1", ls=":", label="Euler–Bernoulli")
        axes[0].axhline(-1e3 * theory["timoshenko_tip_m"], color="C2", ls=":", label="Timoshenko")
        axes[0].set_ylabel("tip deflection, mm")
        axes[1].plot(h, [r["frequency_hz"] for r in default], "o-", label="FEM")
        axes[1].axhline(ref["frequency_hz"]["value"], color="k", ls="--", label="Richardson reference")
        axes[1].axhline(theory["euler_bernoulli_f1_hz"], color="C1", ls=":", label="Euler–Bernoulli")
        axes[1].set_ylabel("first bending frequency, Hz")
        axes[2].plot(h, [r["decay_rate_per_s"] for r in default], "o-", label="FEM (energy fit)")
        axes[2].axhline(ref["decay_rate_per_s"]["value"], color="k", ls="--", label="Richardson reference")
        axes[2].set_ylabel("amplitude decay rate, 1/s")
        for ax in axes:
            ax.set_xlabel("element size h, mm")
            ax.invert_xaxis()
            ax.grid(True, alpha=0.3)
            ax.legend(fontsize=7)
        fig.tight_layout()
        fig.savefig(os.path.join(folder, "accuracy_convergence.png"), dpi=120)
        lines.append("| quantity | reference (Richardson) | observed order | coarser-triple value | beam theory |")
        lines.append("|---|---|---|---|---|")
        lines.append(f"| tip deflection, mm | {-1e3 * ref['tip_m']['value']:.4f} | {ref['tip_m']['observed_order']:.2f} | "
                     f"{-1e3 * ref['tip_m']['coarse_triple_value']:.4f} | EB {-1e3 * theory['euler_bernoulli_tip_m']:.4f}, "
                     f"Timoshenko {-1e3 * theory['timoshenko_tip_m']:.4f} |")
        lines.append(f"| f1, Hz | {ref['frequency_hz']['value']:.4f} | {ref['frequency_hz']['observed_order']:.2f} | "
                     f"{ref['frequency_hz']['coarse_triple_value']:.4f} | EB {theory['euler_bernoulli_f1_hz']:.4f} |")
        lines.append(f"| decay rate, 1/s | {ref['decay_rate_per_s']['value']:.4f} | "
                     f"{ref['decay_rate_per_s']['observed_order']:.2f} | "
                     f"{ref['decay_rate_per_s']['coarse_triple_value']:.4f} | – |")

    # Physics frame rate vs buffer-model rate (buffer_model_bench).
    bm_path = os.path.join(folder, "buffer_model.jsonl")
    if os.path.exists(bm_path):
        rows = [json.loads(x) for x in open(bm_path) if x.strip().startswith("{")]
        if rows:
            rows.sort(key=lambda r: r["frame_rate_hz"])
            fig, ax = plt.subplots(figsize=(6, 4))
            ax.plot([r["frame_rate_hz"] for r in rows], [r["rms_error_buffer_model"] for r in rows], "o-",
                    label="buffer model F = f0 − K(x − x0)")
            ax.plot([r["frame_rate_hz"] for r in rows], [r["rms_error_zero_order_hold"] for r in rows], "s--",
                    label="zero-order hold of f0")
            ax.set_xscale("log")
            ax.set_yscale("log")
            ax.set_xlabel("physics frame rate, Hz (haptic loop 1 kHz)")
            ax.set_ylabel("RMS force error / peak force")
            ax.grid(True, which="both", alpha=0.3)
            ax.legend(fontsize=7)
            fig.tight_layout()
            fig.savefig(os.path.join(folder, "accuracy_frame_rate.png"), dpi=120)
    stab = os.path.join(folder, "stability.md")
    if os.path.exists(stab):
        lines.append("\n## Stability stress suite (stability_bench)\n")
        lines.append(open(stab).read())
    with open(os.path.join(folder, "summary.md"), "a") as f:
        f.write("\n".join(lines) + "\n")
    print("\n".join(lines))


def plot_cut(folder):
    """cut_bench: cut step time by phase against mesh size (stacked medians)."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    path = os.path.join(folder, "cut_bench.json")
    if not os.path.exists(path):
        return
    data = load(path)
    steps = data.get("step", [])
    if not steps:
        return
    # With two threads the halves overlap (the surface half starts during
    # the topology's remeshing moves, the FEM half follows the event's
    # nodes): the wall time from the event's nodes to the end of both
    # (fem_and_surface_wall) is drawn instead of the two stacked halves.
    phases = [("criterion", "criterion", lambda s: True), ("topology", "topology (CutMesh)", lambda s: True),
              ("fem_update", "FEM update", lambda s: s.get("threads", 1) == 1),
              ("surface_bvh", "surface + BVH + debris", lambda s: s.get("threads", 1) == 1),
              ("fem_and_surface_wall", "event applied (2 threads, wall)", lambda s: s.get("threads", 1) > 1)]
    fig, ax = plt.subplots(figsize=(7, 4))
    x = list(range(len(steps)))
    bottom = [0.0] * len(steps)
    for key, label, shown in phases:
        values = [s[key]["median_us"] if shown(s) and key in s else 0.0 for s in steps]
        if not any(values):
            continue
        ax.bar(x, values, bottom=bottom, label=label)
        bottom = [b + v for b, v in zip(bottom, values)]
    # The step's wall time: with two threads less than the stack (the
    # criterion also runs beside the topology's walk).
    ax.plot(x, [s["total"]["median_us"] for s in steps], "kD", label="total median (wall)")
    ax.plot(x, [s["total"]["p90_us"] for s in steps], "k^", label="total p90")
    ax.axhline(50.0, color="r", ls="--", label="target 50 µs")
    ax.set_xticks(x)
    ax.set_xticklabels([f"{s['tets']} tets\n{s.get('threads', 1)} thread" + ("s" if s.get("threads", 1) > 1 else "")
                        for s in steps], fontsize=8)
    ax.set_ylabel("wall time per cut step, µs (median by phase)")
    ax.grid(True, axis="y", alpha=0.3)
    ax.legend(fontsize=7)
    fig.tight_layout()
    fig.savefig(os.path.join(folder, "cut_step.png"), dpi=120)


def plot_poisson(folder):
    """accuracy_bench's Poisson sweep: static tip error against the CalculiX
    reference vs wall time, per element and integrator, one panel per ν,
    with each element's Pareto front (poisson_pareto.png)."""
    path = os.path.join(folder, "accuracy.json")
    if not os.path.exists(path):
        return
    sweep = load(path).get("poisson_sweep")
    if not sweep:
        return
    runs = [r for r in sweep["runs"] if r["ok"]]
    ratios = sorted({r["poisson"] for r in runs})
    fig, axes = plt.subplots(1, len(ratios), figsize=(4.2 * len(ratios), 4.2), squeeze=False)
    styles = {("linear", "backward_euler"): ("tab:red", "o"), ("linear", "symplectic_euler"): ("tab:red", "^"),
              ("nodal_pressure", "backward_euler"): ("tab:blue", "o"),
              ("nodal_pressure", "symplectic_euler"): ("tab:blue", "^")}
    for ax, nu in zip(axes[0], ratios):
        here = [r for r in runs if r["poisson"] == nu]
        for (element, integrator), (color, marker) in styles.items():
            pts = [r for r in here if r["element"] == element and r["integrator"] == integrator]
            if not pts:
                continue
            ax.scatter([r["static_wall_s"] for r in pts], [100 * abs(r["tip_rel_error"]) for r in pts],
                       color=color, marker=marker, label=f"{element}, {integrator.replace('_', ' ')}")
            for r in pts:
                ax.annotate(f"{r['tets']}", (r["static_wall_s"], 100 * abs(r["tip_rel_error"])), fontsize=6,
                            xytext=(3, 3), textcoords="offset points")
        for element, color in (("linear", "tab:red"), ("nodal_pressure", "tab:blue")):
            pts = [(r["static_wall_s"], 100 * abs(r["tip_rel_error"])) for r in here if r["element"] == element]
            front = sorted(pts[i] for i in pareto_front(pts))
            if front:
                ax.plot([p[0] for p in front], [p[1] for p in front], color=color, lw=1, alpha=0.6)
        ax.set_xscale("log")
        ax.set_yscale("log")
        ax.set_title(f"ν = {nu}", fontsize=10)
        ax.set_xlabel("wall time to the static tip, s (1 thread)")
        ax.grid(True, which="both", alpha=0.3)
    axes[0][0].set_ylabel("|tip error| vs CalculiX C3D20R, %")
    max(axes[0], key=lambda a: len(a.get_legend_handles_labels()[0])).legend(fontsize=7)
    fig.suptitle("Beam under gravity: run time against error, both elements", fontsize=11)
    fig.tight_layout()
    fig.savefig(os.path.join(folder, "poisson_pareto.png"), dpi=120)


SCENE_COLORS = {"ligament": "tab:red", "block": "tab:blue", "skin_pad": "tab:green"}


def link_tables(doc):
    """Markdown tables of link_fidelity_bench's JSON (link_fidelity.md)."""
    rows, hand = doc["rows"], doc["hand_rows"]
    delays = sorted({r["one_way_ms"] for r in rows})
    losses = sorted({r["loss"] for r in rows})
    pct = lambda v: f"{100 * v:.0f}"
    out = ["RMS force error of the buffer model, % of the stroke's peak force (unfelt share of the squared "
           "error in brackets), by one-way delay:\n",
           "| scene | stroke | loss | " + " | ".join(f"{d:g} ms" for d in delays) + " |",
           "|---|---|---|" + "---|" * len(delays)]
    for scene in SCENE_COLORS:
        for stroke in ("press_hold", "fast_press", "saw"):
            for loss in losses:
                sel = {r["one_way_ms"]: r for r in rows if r["scene"] == scene and r["stroke"] == stroke
                       and r["loss"] == loss and r["term"] == "buffer_model"}
                if sel:
                    out.append(f"| {scene} | {stroke} | {loss:.0%} | " + " | ".join(
                        f"{pct(sel[d]['rms_error'])} ({pct(sel[d]['unfelt_share'])})" if d in sel else "–"
                        for d in delays) + " |")
    terms = ["buffer_model", "zero_order_hold", "buffer_model_patch_k", "buffer_model_no_pc"]
    out += ["", "Stiff strokes, loss 0: RMS force error, % of peak, per rendering (server K / zero-order hold / "
            "patch-only K / server K without the passivity controller):\n",
            "| scene | stroke | " + " | ".join(f"{d:g} ms" for d in delays) + " |",
            "|---|---|" + "---|" * len(delays)]
    for scene, stroke in (("block", "fast_press"), ("ligament", "press_hold"), ("ligament", "saw"),
                          ("block", "saw"), ("skin_pad", "saw")):
        cells = []
        for d in delays:
            sel = {r["term"]: r for r in rows if r["scene"] == scene and r["stroke"] == stroke and r["loss"] == 0
                   and r["one_way_ms"] == d}
            cells.append(" / ".join(pct(sel[t]["rms_error"]) if t in sel else "–" for t in terms))
        out.append(f"| {scene} | {stroke} | " + " | ".join(cells) + " |")
    out += ["", "Virtual hand on the press-and-hold, buffer model with the passivity controller: tool peak-to-peak "
            "(µm), force peak-to-peak / mean hold force, hold force (mN), energy the controller removed (µJ), "
            "E_obs of the same rendering without the controller (µJ; < 0: energy it would put into the hand), "
            "watchdog trips:\n",
            "| scene | delay | loss | tool p2p | force ripple | hold force | PC removed | E_obs without PC | trips |",
            "|---|---|---|---|---|---|---|---|---|"]
    for scene in SCENE_COLORS:
        for loss in losses:
            for d in delays:
                sel = {r["term"]: r for r in hand if r["scene"] == scene and r["loss"] == loss
                       and r["one_way_ms"] == d}
                b, n = sel.get("buffer_model"), sel.get("buffer_model_no_pc")
                if not b:
                    continue
                ripple = b["force_p2p_n"] / max(abs(b["hold_force_n"]), 1e-12)
                out.append(f"| {scene} | {d:g} ms | {loss:.0%} | {1e6 * b['oscillation_p2p_m']:.1f} | "
                           f"{100 * ripple:.0f} % | {1e3 * b['hold_force_n']:.1f} | {1e6 * b['pc_dissipated_j']:.1f} | "
                           f"{1e6 * n['energy_j'] if n else float('nan'):.2f} | {b['watchdog_trips']} |")
    out += ["", f"Targets missed: {len(doc['missed'])}; goals missed: {len(doc['goals_missed'])}.", ""]
    return "\n".join(out)


def plot_link(folder):
    """link_fidelity_bench: force error, energy into the hand and the hand's
    oscillation against one-way delay, one line per scene (link_fidelity.png),
    and the block's fast press at 0, 25 and 100 ms beside the reference
    (link_fidelity_trace.png)."""
    path = os.path.join(folder, "link_fidelity.json")
    if not os.path.exists(path):
        return
    doc = load(path)
    rows, hand = doc["rows"], doc["hand_rows"]
    scenes = [s for s in SCENE_COLORS if any(r["scene"] == s for r in rows)]
    delays = sorted({r["one_way_ms"] for r in rows})
    fig, axes = plt.subplots(1, 4, figsize=(20, 4.6))

    def by_delay(select, value, reduce=max):
        out = []
        for d in delays:
            vals = [value(r) for r in select if r["one_way_ms"] == d]
            out.append(reduce(vals) if vals else float("nan"))
        return out

    ax = axes[0]
    for scene in scenes:
        for loss, style in ((0.0, "o-"), (0.05, "s--")):
            sel = [r for r in rows if r["scene"] == scene and r["loss"] == loss and r["term"] == "buffer_model"]
            if sel:
                ax.plot(delays, by_delay(sel, lambda r: 100 * r["rms_error"]), style, color=SCENE_COLORS[scene],
                        label=f"{scene}, loss {loss:.0%}")
    ax.plot([25, 50], [10, 20], "kv", ms=9, label="targets: 10 % at 25 ms, 20 % at 50 ms")
    ax.axhline(10, color="k", ls=":", lw=1, label="10 % budget")
    ax.set_xlabel("one-way delay, ms (±20 % jitter)")
    ax.set_ylabel("RMS force error, % of peak (worst stroke)")
    ax.set_title("Buffer model: force the device gets vs in-process", fontsize=10)
    ax.legend(fontsize=7)

    ax = axes[1]
    styles = {"buffer_model": "o-", "zero_order_hold": "x:", "buffer_model_patch_k": "^--"}
    for scene in scenes:
        for term, style in styles.items():
            sel = [r for r in rows if r["scene"] == scene and r["loss"] == 0.0 and r["term"] == term
                   and r["stroke"] in ("fast_press", "saw", "press_hold")]
            if sel:
                ax.plot(delays, by_delay(sel, lambda r: 100 * r["rms_error"]), style, color=SCENE_COLORS[scene],
                        label=f"{scene}: {term.replace('_', ' ')}", lw=1)
    ax.set_xlabel("one-way delay, ms")
    ax.set_ylabel("RMS force error, % of peak (worst stroke, loss 0)")
    ax.set_title("Stiffness term: server K, none (ZOH), patch-only K", fontsize=10)
    ax.legend(fontsize=6, ncol=1)

    ax = axes[2]
    for scene in scenes:
        for term, style in (("buffer_model", "o-"), ("buffer_model_no_pc", "s--")):
            sel = [r for r in hand if r["scene"] == scene and r["term"] == term]
            if sel:
                ax.plot(delays, by_delay(sel, lambda r: -1e6 * r["energy_j"], max), style,
                        color=SCENE_COLORS[scene], label=f"{scene}: {term.replace('_', ' ')}")
    ax.axhline(0, color="k", lw=1, ls="--", label="0: passive (no net energy into the hand)")
    ax.set_xlabel("one-way delay, ms")
    ax.set_ylabel("net energy into the hand, µJ (−E_obs, worst loss)")
    ax.set_title("Virtual hand holding the press", fontsize=10)
    ax.legend(fontsize=7)

    ax = axes[3]
    limit = 1e6 * doc["oscillation_limit_m"]
    for scene in scenes:
        for term, style in (("buffer_model", "o-"), ("zero_order_hold", "x:"), ("buffer_model_patch_k", "^--")):
            sel = [r for r in hand if r["scene"] == scene and r["term"] == term]
            if sel:
                ax.plot(delays, by_delay(sel, lambda r: max(1e6 * r["oscillation_p2p_m"], 1e-3)), style,
                        color=SCENE_COLORS[scene], label=f"{scene}: {term.replace('_', ' ')}", lw=1)
    ax.axhline(limit, color="r", ls="--", label=f"stability limit {limit:g} µm")
    ax.set_yscale("log")
    ax.set_xlabel("one-way delay, ms")
    ax.set_ylabel("tool peak-to-peak at the end of the hold, µm")
    ax.set_title("Stability under the virtual hand (worst loss)", fontsize=10)
    ax.legend(fontsize=6)
    for a in axes:
        a.grid(True, alpha=0.3)
    fig.tight_layout()
    fig.savefig(os.path.join(folder, "link_fidelity.png"), dpi=110)

    with open(os.path.join(folder, "link_fidelity.md"), "w") as f:
        f.write(link_tables(doc))

    trace_path = os.path.join(folder, "link_fidelity_trace.json")
    if not os.path.exists(trace_path):
        return
    trace = load(trace_path)
    dt = trace["dt"]
    fig, ax = plt.subplots(figsize=(9, 4.6))
    ref = trace["reference"]
    ax.plot([i * dt for i in range(len(ref))], ref, "k-", lw=2.5, alpha=0.5, label="reference (in-process, 1 kHz)")
    colors = {0: "tab:blue", 25: "tab:orange", 100: "tab:red"}
    for run in trace["runs"]:
        if run["term"] == "buffer_model_patch_k":
            continue
        style = {"buffer_model": "-", "zero_order_hold": ":"}.get(run["term"], "--")
        ax.plot([i * dt for i in range(len(run["force"]))], run["force"], style,
                color=colors.get(int(run["one_way_ms"]), "gray"), lw=1.2,
                label=f"{run['term'].replace('_', ' ')}, {run['one_way_ms']:g} ms one-way")
    ax.set_xlabel("time, s")
    ax.set_ylabel("force on the tool along the normal, N")
    ax.set_title(f"{trace['scene']}: {trace['stroke'].replace('_', ' ')} (10 cm/s), loss 0", fontsize=10)
    ax.grid(True, alpha=0.3)
    ax.legend(fontsize=7)
    fig.tight_layout()
    fig.savefig(os.path.join(folder, "link_fidelity_trace.png"), dpi=110)


if __name__ == "__main__":
    if len(sys.argv) > 2 and sys.argv[2] == "link":
        plot_link(sys.argv[1])
        sys.exit(0)
    plot_link(sys.argv[1] if len(sys.argv) > 1 else "out/bench")
    main(sys.argv[1] if len(sys.argv) > 1 else "out/bench")
    plot_accuracy(sys.argv[1] if len(sys.argv) > 1 else "out/bench")
    plot_cut(sys.argv[1] if len(sys.argv) > 1 else "out/bench")
    plot_poisson(sys.argv[1] if len(sys.argv) > 1 else "out/bench")

#!/usr/bin/env python3
"""Summarises a demo session in out/: a force-over-time plot and summary.json.

Reads the JSON each process wrote (server.json, haptic.json, viewer*.json,
block.json, organ-*.json) and the haptic CSV; prints where everything is.
"""
import csv
import json
import os
import sys

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402


def load_json(path):
    """The last JSON object line of a file, or None."""
    if not os.path.exists(path):
        return None
    with open(path) as f:
        for line in reversed(f.read().strip().splitlines()):
            line = line.strip()
            if line.startswith("{"):
                return json.loads(line)
    return None


def main(out):
    rows = []
    with open(os.path.join(out, "haptic.csv")) as f:
        for r in csv.DictReader(f):
            rows.append(r)
    t = [float(r["t_s"]) for r in rows]
    force = [float(r["f_n"]) for r in rows]
    cuts = [int(r["cuts"]) for r in rows]
    cut_times = [t[i] for i in range(1, len(t)) if cuts[i] > cuts[i - 1]]

    fig, ax = plt.subplots(figsize=(8, 3.5), dpi=120)
    ax.plot(t, force, lw=1.0, label="rendered force |F|")
    for k, ct in enumerate(cut_times):
        ax.axvline(ct, color="tab:orange", ls="--", lw=1, label="cut (decay e^(-ξt) starts)" if k == 0 else None)
    ax.set_xlabel("time [s]")
    ax.set_ylabel("force [N]")
    ax.set_title("cutsim demo: haptic force while cutting the ligament (1 kHz)")
    ax.grid(alpha=0.3)
    ax.legend(loc="upper right")
    fig.tight_layout()
    plot = os.path.join(out, "haptic-force.png")
    fig.savefig(plot)

    summary = {
        "server": load_json(os.path.join(out, "server.json")),
        "haptic": load_json(os.path.join(out, "haptic.json")),
        "viewer": load_json(os.path.join(out, "viewer.json")),
        "viewer_late": load_json(os.path.join(out, "viewer-late.json")),
        "headless_block": load_json(os.path.join(out, "block.json")),
        "organ_server": load_json(os.path.join(out, "organ-server.json")),
        "organ_haptic": load_json(os.path.join(out, "organ-haptic.json")),
        "organ_viewer": load_json(os.path.join(out, "organ-viewer.json")),
        "haptic_cut_times_s": cut_times,
        "haptic_peak_force_n": max(force) if force else 0.0,
    }
    tmp = os.path.join(out, "summary.json.tmp")
    with open(tmp, "w") as f:
        json.dump(summary, f, indent=2)
    os.replace(tmp, os.path.join(out, "summary.json"))

    s, h, v, vl, b = (summary[k] for k in ("server", "haptic", "viewer", "viewer_late", "headless_block"))
    print("== demo results (in %s)" % out)
    if s:
        print("  session: %d physics frames, %d cut steps, %d parts, %d frame overruns (p99 frame %.1f ms)"
              % (s["frames"], s["cuts"], s["components"], s["frame_overruns"], s["frame_time_p99_ms"]))
    if h:
        print("  haptic: %d ticks at %d Hz, jitter p99 %.0f µs, %d missed deadlines, %d cut decays, peak %.2f N"
              % (h["ticks"], h["rate_hz"], h["jitter_us"]["p99"], h["missed_deadlines"], h["cut_decays"],
                 summary["haptic_peak_force_n"]))
    for name, vv in (("viewer", v), ("late viewer", vl)):
        if vv:
            print("  %s: %d verified frames, %d resyncs, %d hash mismatches, joined in %.2f s"
                  % (name, vv["verified_frames"], vv["resyncs"], vv["hash_mismatches"], vv["join_latency_s"]))
    if b:
        print("  headless block: %d cut steps, %d parts, wall %.1f s" % (b["cuts"], b["components"], b["wall_time"]))
    o, ov = summary["organ_server"], summary["organ_viewer"]
    if o:
        print("  organ session: %d physics frames, %d cut steps, %d parts, %d frame overruns (p99 frame %.1f ms)"
              % (o["frames"], o["cuts"], o["components"], o["frame_overruns"], o["frame_time_p99_ms"]))
    if ov:
        print("  organ viewer: %d verified frames, %d resyncs, %d hash mismatches"
              % (ov["verified_frames"], ov["resyncs"], ov["hash_mismatches"]))
    print("  frames:       %s/frames/, %s/frames-late/ and %s/organ-frames/" % (out, out, out))
    if os.path.exists(os.path.join(out, "session.mp4")):
        print("  video:        %s/session.mp4" % out)
    print("  force plot:   %s" % plot)
    print("  haptic CSV:   %s/haptic.csv" % out)
    print("  block .vtu:   %s/block.vtu (ParaView: cell array cut_faces)" % out)
    print("  summary:      %s/summary.json" % out)


if __name__ == "__main__":
    main(sys.argv[1] if len(sys.argv) > 1 else "out")

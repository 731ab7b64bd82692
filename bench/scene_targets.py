#!/usr/bin/python3
"""Checks the real-time targets of the shipped scenes on bench.sh's JSON.

Reads OUT/scene_<name>.json (one headless server summary each) and prints
one JSON object: per scene its real-time factor, integrator and target, and
whether the target is met. Exits 1 when a target is missed, 2 on bad input.

Targets (real-time factor = simulated s per wall s, on this machine's cores):
  organ  >= 1.5  (real time at organ scale, with headroom for the session)
  block  >= 3.0  (headroom for a real-time session's pacing and link)
  organ_large >= 0.5 (the organ at ~109k tets, bench/scenes; a stretch target)
  ligament, beam: reported, no target.
"""
import json
import math
import sys
from pathlib import Path

TARGETS = {"organ": 1.5, "block": 3.0, "organ_large": 0.5}


def main() -> int:
    if len(sys.argv) != 2:
        print("usage: scene_targets.py OUT_DIR", file=sys.stderr)
        return 2
    out = Path(sys.argv[1])
    report, missed = {}, []
    for scene in ("ligament", "beam", "block", "organ", "organ_large"):
        path = out / f"scene_{scene}.json"
        try:
            summary = json.loads(path.read_text())
        except (OSError, ValueError) as e:
            print(f"{path}: {e}", file=sys.stderr)
            missed.append(scene)
            continue
        factor = summary.get("realtime_factor")
        if not isinstance(factor, (int, float)) or not math.isfinite(factor):
            print(f"{path}: field realtime_factor missing or not a number", file=sys.stderr)
            missed.append(scene)
            continue
        entry = {
            "realtime_factor": factor,
            "cuts": summary.get("cuts"),
            "integrator": summary.get("integrator", "explicit"),
            "tets": summary.get("tets"),
            "threads": summary.get("threads"),
            "dt": summary.get("dt"),
            "status": summary.get("status"),
        }
        target = TARGETS.get(scene)
        if target is not None:
            entry["target"] = target
            entry["met"] = factor >= target and summary.get("status") == "ok"
            if not entry["met"]:
                missed.append(scene)
        report[scene] = entry
    report["missed"] = missed
    print(json.dumps(report, indent=2))
    return 1 if missed else 0


if __name__ == "__main__":
    sys.exit(main())

"""Runs CalculiX (ccx) on a deck in a temporary directory and reads its .dat.

ccx runs single-threaded (OMP_NUM_THREADS=1) under a wall-time limit; a
missing binary, a timeout or a failed solve raises CcxError with the deck and
the tail of ccx's log.
"""

import os
import re
import shutil
import subprocess
import tempfile
import time

_BLOCK_RE = re.compile(r"^\s*(displacements|total force|forces)\s.*for set (\S+) and time\s+(\S+)")


class CcxError(RuntimeError):
    pass


def find_ccx(explicit=None):
    """Path of the ccx binary, or None when it is not installed."""
    if explicit:
        return explicit if os.access(explicit, os.X_OK) else None
    return shutil.which("ccx")


def ccx_version(ccx):
    out = subprocess.run([ccx, "-v"], capture_output=True, text=True, timeout=30).stdout
    match = re.search(r"Version\s+(\S+)", out)
    return match.group(1) if match else "unknown"


def run(ccx, write_deck, timeout_s, keep_dir=None):
    """Writes the deck with write_deck(path) and solves it.

    Returns (dat blocks, wall seconds); dat blocks map (kind, set) to the
    rows of the last time printed: kind "U" → {node id: (ux, uy, uz)},
    kind "RF_TOTAL" → (fx, fy, fz).
    """
    workdir = keep_dir or tempfile.mkdtemp(prefix="cutsim-ccx-")
    try:
        deck = os.path.join(workdir, "job.inp")
        write_deck(deck)
        env = dict(os.environ, OMP_NUM_THREADS="1", CCX_NPROC_EQUATION_SOLVER="1")
        start = time.monotonic()
        try:
            proc = subprocess.run([ccx, "-i", "job"], cwd=workdir, env=env, capture_output=True, text=True,
                                  timeout=timeout_s)
        except subprocess.TimeoutExpired as e:
            raise CcxError(f"ccx exceeded {timeout_s:.0f} s on {deck}") from e
        wall = time.monotonic() - start
        log = proc.stdout + proc.stderr
        if proc.returncode != 0 or "*ERROR" in log or "Job finished" not in log:
            tail = "\n".join(log.strip().splitlines()[-15:])
            raise CcxError(f"ccx failed on {deck} (exit {proc.returncode}):\n{tail}")
        return parse_dat(os.path.join(workdir, "job.dat")), wall
    finally:
        if keep_dir is None:
            shutil.rmtree(workdir, ignore_errors=True)


def parse_dat(path):
    """Reads the blocks of a ccx .dat file, keeping each set's last time."""
    blocks, times = {}, {}
    current = None
    with open(path, encoding="ascii", errors="replace") as f:
        for line in f:
            header = _BLOCK_RE.match(line)
            if header:
                kind = {"displacements": "U", "total force": "RF_TOTAL", "forces": "RF"}[header.group(1)]
                key = (kind, header.group(2).upper())
                t = float(header.group(3))
                if t >= times.get(key, -1.0):
                    times[key] = t
                    blocks[key] = {} if kind != "RF_TOTAL" else None
                    current = key
                else:
                    current = None
                continue
            fields = line.split()
            if current is None or not fields:
                continue
            if current[0] == "RF_TOTAL":
                blocks[current] = tuple(float(v) for v in fields[:3])
            else:
                blocks[current][int(fields[0])] = tuple(float(v) for v in fields[1:4])
    for key, t in times.items():
        if abs(t - 1.0) > 1e-9:
            raise CcxError(f"{path}: set {key[1]} printed up to time {t}, not the end of the step (1.0)")
    return blocks

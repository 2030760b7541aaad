#!/usr/bin/env python3
"""How well a rope's clamp holds it: for every pair of particles adjacent at rest, one held by
the clamp and one free, the stretch |x_c - x_f| / rest - 1 on each frame of `morph rope`'s
uncontrolled run; prints the largest and plots the largest per frame.

    python3 scripts/rope_junction.py OUT.png LABEL=ROPE_OUT [LABEL=ROPE_OUT ...]

The held particles are those that never move in the first folder's uncontrolled run (its
clamp holds still), and the same particles are used for every folder. Needs numpy and
matplotlib (e.g. a venv outside the repo: python3 -m venv ~/.cache/morph-plot-venv &&
~/.cache/morph-plot-venv/bin/pip install numpy matplotlib).
"""
import glob
import json
import os
import sys

import matplotlib
import numpy as np

matplotlib.use("Agg")
import matplotlib.pyplot as plt

POINT = np.dtype([(n, "<f4") for n in ("x", "y", "z", "vx", "vy", "vz", "J")] + [("id", "<i4")])


def positions(path):
    """Particle positions of one PLY frame, in particle order."""
    data = open(path, "rb").read()
    body = data.index(b"end_header\n") + len(b"end_header\n")
    header = data[:body].decode()
    n = int(next(l for l in header.splitlines() if l.startswith("element vertex")).split()[-1])
    rec = np.sort(np.frombuffer(data[body : body + n * POINT.itemsize], dtype=POINT), order="id")
    return np.stack([rec["x"], rec["y"], rec["z"]], 1).astype(float)


def stretch(folder, held):
    """Frame times and the junction's largest stretch on each frame."""
    report = json.load(open(os.path.join(folder, "report.json")))
    frames = [positions(f) for f in sorted(glob.glob(os.path.join(folder, "frames/uncontrolled/*.ply")))]
    rest = frames[0]
    if held is None:
        moved = np.max([np.abs(x - rest).max(axis=1) for x in frames], axis=0)
        held = np.where(moved < 1e-6)[0]
    free = np.setdiff1d(np.arange(len(rest)), held)
    d0 = np.linalg.norm(rest[held][:, None] - rest[free][None], axis=2)
    pairs = np.argwhere(d0 < d0.min() * 1.01)
    r0 = d0[pairs[:, 0], pairs[:, 1]]
    worst = [np.max(np.linalg.norm(x[held][pairs[:, 0]] - x[free][pairs[:, 1]], axis=1) / r0 - 1) for x in frames]
    settings = report["settings"]
    step = settings["frame_every"] * settings["rope"]["dt"]
    times = [k * step for k in range(len(frames))]
    return held, times, worst


def main():
    out, runs = sys.argv[1], [a.split("=", 1) for a in sys.argv[2:]]
    held = None
    fig, ax = plt.subplots(figsize=(7, 3.5))
    for label, folder in runs:
        held, times, worst = stretch(folder, held)
        print(f"{label}: {len(held)} held particles, largest stretch {100 * max(worst):.1f}% at {times[int(np.argmax(worst))]:.2f} s")
        ax.plot(times, [100 * w for w in worst], label=label)
    ax.set_xlabel("time (s)")
    ax.set_ylabel("clamp junction's largest stretch (%)")
    ax.legend()
    fig.tight_layout()
    fig.savefig(out, dpi=120)


if __name__ == "__main__":
    main()

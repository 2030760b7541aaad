#!/usr/bin/env python3
"""Plots the motion of morph outputs from their manifests: the rms particle speed s(f) with the
segment boundaries, and progress toward the target against the easing curve.

    python3 scripts/plot_motion.py OUT.png LABEL=DIR [LABEL=DIR ...]

Needs matplotlib (e.g. a venv outside the repo: python3 -m venv ~/.cache/morph-plot-venv &&
~/.cache/morph-plot-venv/bin/pip install matplotlib).
"""
import json
import sys

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt


def load(folder):
    m = json.load(open(f"{folder}/manifest.json"))
    frames = m["frames"]
    speed = [f["rms_speed"] for f in frames]
    iou = [f["progress_iou"][-1] for f in frames]
    # Progress and the easing curve count from the frame the shape change begins on.
    begin = m["settings"]["shot"].get("begin", 1)
    start = iou[begin - 1]
    progress = [(x - start) / (iou[-1] - start) for x in iou]
    every = m["settings"]["shot"]["frame_every"]
    steps = m["settings"]["method"]["steps_per_segment"]
    boundaries = list(range(1 + steps // every, len(frames) + 1, steps // every))
    arrive = m["settings"]["shot"]["at"][-1]
    return speed, progress, boundaries, arrive, begin, m.get("motion") or {}


def main():
    out, runs = sys.argv[1], [a.split("=", 1) for a in sys.argv[2:]]
    fig, (a, b) = plt.subplots(1, 2, figsize=(11, 3.8))
    curves = set()
    for label, folder in runs:
        speed, progress, boundaries, arrive, begin, motion = load(folder)
        f = range(1, len(speed) + 1)
        tag = f"{label}: pulse {motion.get('pulse', 0):.2f}, wobble {motion.get('wobble', 0):.2f}, settle {motion.get('settle', 0):.2f}"
        a.plot(f, speed, marker=".", label=tag)
        e = motion.get("ease_error")
        b.plot(f, progress, marker=".", label=f"{label}: ease error {e:.2f}" if e is not None else label)
        if begin > 1:
            a.axvline(begin, color="k", lw=0.8, ls=":", zorder=0)
        curves.add((begin, arrive, len(speed)))
    for x in boundaries:
        a.axvline(x, color="0.85", lw=0.8, zorder=0)
    for begin, arrive, n in sorted(curves):
        ease = [min(1.0, max(0.0, (i - begin) / (arrive - begin))) for i in range(1, n + 1)]
        name = "easing curve (smoothstep)" + (f" from frame {begin}" if begin > 1 else "")
        b.plot(range(1, n + 1), [u * u * (3 - 2 * u) for u in ease], "k--" if begin == 1 else "k:", label=name)
    a.set(xlabel="frame", ylabel="rms particle speed (units/s)", title="speed s(f); grey: segment boundaries; dotted: begin")
    b.set(xlabel="frame", ylabel="progress (IoU gain, 0..1)", title="progress toward the target")
    a.legend(fontsize=7)
    b.legend(fontsize=7)
    fig.tight_layout()
    fig.savefig(out, dpi=110)


if __name__ == "__main__":
    main()

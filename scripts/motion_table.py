#!/usr/bin/env python3
"""Prints a markdown table of the motion measures, fill and wall time of morph outputs.

    python3 scripts/motion_table.py times.txt LABEL=DIR [LABEL=DIR ...]

times.txt holds lines `<label> wall <seconds>` (as `/usr/bin/time -f "<label> wall %e"`
writes them); a run's keyframe sections are listed under it when it has several targets.
"""
import json
import sys


def row(label, m, wall):
    mo = m.get("motion") or {}
    q = m.get("quality") or {}
    ease = mo.get("ease_error")
    ease = f"{ease:.2f}" if ease is not None else "n/a"
    return (f"| {label} | {mo.get('pulse', 0):.2f} | {mo.get('dip', 0):.2f} | {mo.get('wobble', 0):.2f} "
            f"| {mo.get('settle', 0):.2f} | {ease} | {mo.get('frozen_frames', 0)} | {q.get('fill', 0):.3f} | {wall} |")


def main():
    walls = {}
    for line in open(sys.argv[1]):
        parts = line.split()
        if len(parts) == 3 and parts[1] == "wall":
            walls[parts[0]] = parts[2]
    print("| run | pulse | dip | wobble | settle | ease error | frozen | fill | wall s |")
    print("|---|---|---|---|---|---|---|---|---|")
    for arg in sys.argv[2:]:
        label, folder = arg.split("=", 1)
        m = json.load(open(f"{folder}/manifest.json"))
        print(row(label, m, walls.get(label, "")))
        keys = m.get("keyframes") or []
        if len(keys) > 1:
            for t, k in enumerate(keys):
                print(row(f"{label}, keyframe {t + 1} (frame {k['frame']})", {"motion": k.get("motion"), "quality": k.get("quality")}, ""))


if __name__ == "__main__":
    main()

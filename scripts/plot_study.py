#!/usr/bin/env python3
"""Plots what accuracy costs from `morph study` folders: the judge's IoU, the reach (the
farthest part of the target no particle reaches, in spacings) and the pulse against wall
seconds, one column of panels per study. Colour: the particle budget (or resolution);
marker: the reach weight (circle 0, triangle otherwise); filled: the most iterations of the
study, hollow: fewer; ringed in black on the IoU panel: the study's Pareto front (IoU
against wall time).

    python3 scripts/plot_study.py [--cpu] OUT.png LABEL=STUDY_DIR [LABEL=STUDY_DIR ...]

--cpu plots CPU seconds instead of wall seconds, and rings the front on them (for studies run
beside other work, where the wall seconds include waiting for a core).

Needs matplotlib (e.g. a venv outside the repo: python3 -m venv ~/.cache/morph-plot-venv &&
~/.cache/morph-plot-venv/bin/pip install matplotlib).
"""
import json
import sys

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt
import matplotlib.ticker


def rows(folder):
    study = json.load(open(f"{folder}/study.json"))
    return [r for r in study["rows"] if r.get("quality")]


def detail(r):
    c = r["config"]
    return f"{c['particles']:,} particles" if c.get("particles") else f"resolution {c['resolution']}"


def front(rs, seconds):
    """The rows no other row beats on both IoU (higher) and `seconds` (lower)."""
    pts = [(seconds(r), r["quality"]["iou"]) for r in rs]
    return [
        not any(t2 <= t and q2 >= q and (t2 < t or q2 > q) for j, (t2, q2) in enumerate(pts) if j != i)
        for i, (t, q) in enumerate(pts)
    ]


def main():
    args = sys.argv[1:]
    cpu = "--cpu" in args
    args = [a for a in args if a != "--cpu"]
    out, studies = args[0], [a.split("=", 1) for a in args[1:]]
    seconds = (lambda r: r["cpu_s"]) if cpu else (lambda r: r["wall_s"])
    panels = [
        ("IoU with the target", lambda r: r["quality"]["iou"]),
        ("reach max (spacings)", lambda r: r["quality"]["reach_max"]),
        ("pulse", lambda r: (r.get("motion") or {}).get("pulse")),
    ]
    fig, axes = plt.subplots(
        len(panels), len(studies), figsize=(5.2 * len(studies), 3.2 * len(panels)), squeeze=False
    )
    for col, (label, folder) in enumerate(studies):
        rs = rows(folder)
        details = sorted({detail(r) for r in rs}, key=lambda d: min(r["particles"] for r in rs if detail(r) == d))
        colours = {d: plt.cm.viridis(i / max(1, len(details) - 1)) for i, d in enumerate(details)}
        most = max(r["config"]["iterations"] for r in rs)
        on_front = front(rs, seconds)
        for row, (name, value) in enumerate(panels):
            ax = axes[row][col]
            for r, pareto in zip(rs, on_front):
                v = value(r)
                if v is None:
                    continue
                c = colours[detail(r)]
                filled = r["config"]["iterations"] == most
                marker = "o" if r["config"].get("reach_weight", 0) == 0 else "^"
                ax.scatter(
                    seconds(r),
                    v,
                    marker=marker,
                    s=46,
                    facecolors=c if filled else "none",
                    edgecolors=c,
                    linewidths=1.4,
                )
                if pareto and row == 0:
                    ax.scatter(seconds(r), v, marker=marker, s=150, facecolors="none", edgecolors="black", linewidths=1.0)
            ax.set_xscale("log")
            ax.xaxis.set_major_formatter(matplotlib.ticker.FuncFormatter(lambda x, _: f"{x:g}"))
            ax.xaxis.set_minor_formatter(matplotlib.ticker.NullFormatter())
            ax.set_xlabel("CPU seconds" if cpu else "wall seconds")
            ax.set_ylabel(name)
            ax.grid(alpha=0.3)
            if row == 0:
                ax.set_title(label)
        for d in details:
            axes[0][col].scatter([], [], color=colours[d], label=d)
        axes[0][col].scatter([], [], marker="^", color="grey", label="reach weight > 0")
        axes[0][col].scatter([], [], marker="o", facecolors="none", edgecolors="grey", label=f"fewer than {most} iterations")
        axes[0][col].scatter([], [], marker="o", s=150, facecolors="none", edgecolors="black", label="Pareto front")
        axes[0][col].legend(fontsize=7, loc="lower right")
    fig.tight_layout()
    fig.savefig(out, dpi=110)


if __name__ == "__main__":
    main()

#!/usr/bin/env python3
"""Draws where the quality judge finds a morph's last frame short: a slice through the target,
its judge points coloured covered (green), missed (red: inside the target, no particle within
0.75 initial spacings) and extra (blue: covered, outside the target).

    python3 scripts/plot_judge_slices.py OUT.png TARGET_MESH LABEL=DIR [LABEL=DIR ...]

It follows the definitions of `src/morph/quality.rs` (a lattice of 96 points along the
target's longest side, the run's placement and spacing from its manifest), recomputed here for
the picture; the figures to quote are the manifest's. The slice is the plane through the
middle of the target's second-longest axis. Needs numpy, scipy, trimesh and matplotlib (e.g.
the client check's venv: ~/.cache/morph-client-venv/bin/pip install scipy trimesh matplotlib).
"""
import json
import sys

import matplotlib
import numpy as np
import trimesh
from scipy.spatial import cKDTree

matplotlib.use("Agg")
import matplotlib.pyplot as plt

JUDGE_ACROSS = 96
COVER_RADIUS = 0.75


def last_frame_points(folder, manifest):
    path = f"{folder}/{manifest['frames'][-1]['points']}"
    with open(path, "rb") as f:
        count, props = None, []
        while True:
            line = f.readline().decode().strip()
            if line.startswith("element vertex"):
                count = int(line.split()[-1])
            elif line.startswith("property"):
                props.append((line.split()[1], line.split()[2]))
            elif line == "end_header":
                break
        types = {"float": "<f4", "double": "<f8", "int": "<i4", "uint": "<u4", "uchar": "u1"}
        dtype = np.dtype([(name, types[t]) for t, name in props])
        rows = np.frombuffer(f.read(count * dtype.itemsize), dtype=dtype, count=count)
    return np.stack([rows["x"], rows["y"], rows["z"]], 1).astype(float)


def judge(folder, mesh_path):
    m = json.load(open(f"{folder}/manifest.json"))
    points = last_frame_points(folder, m)
    mesh = trimesh.load(mesh_path, force="mesh")
    mesh.apply_scale(m["target"]["scale"])
    mesh.apply_translation(m["target"]["translation"])
    lo, hi = mesh.bounds
    step = (hi - lo).max() / (JUDGE_ACROSS - 1)
    axes = [np.arange(lo[i], hi[i] + step, step) for i in range(3)]
    lattice = np.stack(np.meshgrid(*axes, indexing="ij"), -1).reshape(-1, 3)
    inside = np.concatenate([mesh.contains(lattice[i:i + 20000]) for i in range(0, len(lattice), 20000)])
    spacing = m["dx_sim"] * m["sim_to_world"]["scale"] / m["settings"]["particles_per_cell"]
    covered = cKDTree(points).query(lattice, distance_upper_bound=COVER_RADIUS * spacing)[0] < np.inf
    return m, lattice, inside, covered, step, hi - lo


def main():
    out, mesh_path, runs = sys.argv[1], sys.argv[2], sys.argv[3:]
    fig, axes = plt.subplots(len(runs), 1, figsize=(8, 3.2 * len(runs)), squeeze=False)
    for ax, run in zip(axes[:, 0], runs):
        label, folder = run.split("=", 1)
        m, lattice, inside, covered, step, extent = judge(folder, mesh_path)
        order = np.argsort(extent)[::-1]
        a, b, c = order[0], order[2], order[1]
        middle = np.median(lattice[inside][:, c])
        sel = np.abs(lattice[:, c] - middle) < step / 2
        for mask, colour, name in [
            (inside & covered, "tab:green", "covered"),
            (inside & ~covered, "tab:red", "missed"),
            (~inside & covered, "tab:blue", "extra"),
        ]:
            pts = lattice[sel & mask]
            ax.scatter(pts[:, a], pts[:, b], s=3, c=colour, label=name)
        q = m["quality"]
        ax.set_title(f"{label}: fill {q['fill']:.3f}, IoU {q['iou']:.3f}, "
                     f"missed {(inside & ~covered).sum()} / extra {(~inside & covered).sum()} of {inside.sum()} inside", fontsize=9)
        ax.set_aspect("equal")
        ax.set_xticks([])
        ax.set_yticks([])
    axes[0, 0].legend(loc="upper right", fontsize=7, markerscale=3)
    fig.tight_layout()
    fig.savefig(out, dpi=90)


if __name__ == "__main__":
    main()

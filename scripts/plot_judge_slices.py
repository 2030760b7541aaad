#!/usr/bin/env python3
"""Draws where the quality judge finds a morph's last frame short: a slice through the target,
its judge points coloured covered (green), missed (red: inside the target, no particle within
0.75 initial spacings) and extra (blue: covered, outside the target).

    python3 scripts/plot_judge_slices.py [--material] OUT.png TARGET_MESH LABEL=DIR [LABEL=DIR ...]

With --material, each run gets a second panel: the material cover of `quality.material_fill`
(a point in some particle's rest cell, 1.1 spacings wide, carried by the deformation fitted
to its rest neighbours within 1.5 spacings; the identity where the fit fails), recomputed
from the first and last frames on the slice only.

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


def frame_points(folder, manifest, k):
    """Frame k's particle positions in particle-id order."""
    path = f"{folder}/{manifest['frames'][k]['points']}"
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
    order = np.argsort(rows["id"])
    return np.stack([rows["x"], rows["y"], rows["z"]], 1).astype(float)[order]


def material_cover(folder, manifest, points, spacing):
    """Which of `points` lie in a particle's fitted deformed rest cell (quality.rs's rule)."""
    rest, x = frame_points(folder, manifest, 0), frame_points(folder, manifest, -1)
    covered = np.zeros(len(points), bool)
    near = cKDTree(points)
    tree = cKDTree(rest)
    half = 0.55 * spacing
    for i, n in enumerate(tree.query_ball_point(rest, 1.5 * spacing)):
        f = np.eye(3)
        n = [j for j in n if j != i]
        if len(n) >= 4:
            d_rest, d_now = rest[n] - rest[i], x[n] - x[i]
            gram = d_rest.T @ d_rest
            if abs(np.linalg.det(gram)) > 1e-12 * spacing ** 6:
                fit = (d_now.T @ d_rest) @ np.linalg.inv(gram)
                rms = np.sqrt(((d_now - d_rest @ fit.T) ** 2).sum(1).mean())
                reach = np.abs(fit).sum(1) * half
                if rms <= 0.25 * spacing and np.linalg.det(fit) > 0 and reach.max() <= 4 * spacing:
                    f = fit
        candidates = near.query_ball_point(x[i], np.sqrt(3) * half * np.abs(f).sum(1).max())
        if candidates:
            local = (points[candidates] - x[i]) @ np.linalg.inv(f).T
            covered[np.array(candidates)[np.abs(local).max(1) <= half]] = True
    return covered


def judge(folder, mesh_path):
    m = json.load(open(f"{folder}/manifest.json"))
    points = frame_points(folder, m, -1)
    mesh = trimesh.load(mesh_path, force="mesh")
    mesh.apply_scale(m["target"]["scale"])
    mesh.apply_translation(m["target"]["translation"])
    lo, hi = mesh.bounds
    step = (hi - lo).max() / (JUDGE_ACROSS - 1)
    axes = [np.arange(lo[i], hi[i] + step, step) for i in range(3)]
    lattice = np.stack(np.meshgrid(*axes, indexing="ij"), -1).reshape(-1, 3)
    inside = np.concatenate([mesh.contains(lattice[i:i + 20000]) for i in range(0, len(lattice), 20000)])
    spacing = m["dx_sim"] * m["sim_to_world"]["scale"] / m["settings"]["body"]["particles_per_cell"]
    covered = cKDTree(points).query(lattice, distance_upper_bound=COVER_RADIUS * spacing)[0] < np.inf
    return m, lattice, inside, covered, step, hi - lo


def main():
    args = sys.argv[1:]
    material = "--material" in args
    args = [a for a in args if a != "--material"]
    out, mesh_path, runs = args[0], args[1], args[2:]
    panels = [(run, False) for run in runs]
    if material:
        panels = [(run, m) for run in runs for m in (False, True)]
    fig, axes = plt.subplots(len(panels), 1, figsize=(8, 3.2 * len(panels)), squeeze=False)
    for ax, (run, by_material) in zip(axes[:, 0], panels):
        label, folder = run.split("=", 1)
        m, lattice, inside, covered, step, extent = judge(folder, mesh_path)
        order = np.argsort(extent)[::-1]
        a, b, c = order[0], order[2], order[1]
        middle = np.median(lattice[inside][:, c])
        sel = np.abs(lattice[:, c] - middle) < step / 2
        if by_material:
            spacing = m["dx_sim"] * m["sim_to_world"]["scale"] / m["settings"]["body"]["particles_per_cell"]
            covered = covered.copy()
            covered[sel] = material_cover(folder, m, lattice[sel], spacing)
        for mask, colour, name in [
            (inside & covered, "tab:green", "covered"),
            (inside & ~covered, "tab:red", "missed"),
            (~inside & covered, "tab:blue", "extra"),
        ]:
            pts = lattice[sel & mask]
            ax.scatter(pts[:, a], pts[:, b], s=3, c=colour, label=name)
        q = m["quality"]
        if by_material:
            ax.set_title(f"{label}, material cover: material fill {q['material_fill']:.3f}; on this slice "
                         f"missed {(sel & inside & ~covered).sum()} / extra {(sel & ~inside & covered).sum()}", fontsize=9)
        else:
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

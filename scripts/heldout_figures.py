#!/usr/bin/env python3
"""Writes held-out figures with thin parts, which no setting of morph was tuned on, as closed
OBJ meshes: Blender metaballs (capsules and ellipsoids blended into one smooth surface),
converted to a mesh and written with Y up.

    python scripts/heldout_figures.py OUTDIR

- `quadruped.obj`: a long body on four thin legs (about a tenth of its height across), a
  neck and a head, and a thin tail;
- `eared.obj`: a cartoon head on a small body with two large flat disk ears and thin arms;
- `antlered.obj`: a head on a neck with two thin branched horns.

`scripts/heldout_shapes.py` writes the star-shaped ones (horned, tall, lumpy). Together they
are the held-out set of docs/accuracy.md; keep them apart from the meshes settings are tuned on.

Needs the `bpy` module (Blender 4.5 as a Python module, e.g. the client check's venv).
Deterministic: the same files every time. An existing file of the same name is left alone
when it is the same, and refused when it differs.
"""
import os
import sys

import bpy
from mathutils import Quaternion, Vector

# Blender is Z up; the files are Y up (x, y, z) = (x, z, -y).
RESOLUTION = 0.035
# The field threshold, and the share of an element's radius where its surface lies alone
# (Blender's field falls as (1 - (d / r)^2)^3 times 2): radii below are the surfaces'.
THRESHOLD = 0.1
REACH = (1 - (THRESHOLD / 2) ** (1 / 3)) ** 0.5


def ball(mb, co, radius, size=None, rotation=None):
    """An ellipsoid (size: its half axes over `radius`) or a ball, at `co` (Blender axes)."""
    e = mb.elements.new(type="ELLIPSOID" if size else "BALL")
    e.co = Vector(co)
    e.radius = radius / REACH
    if size:
        e.size_x, e.size_y, e.size_z = size
    if rotation:
        e.rotation = rotation
    return e


def capsule(mb, a, b, radius):
    """A capsule from `a` to `b` (a metaball line element)."""
    a, b = Vector(a), Vector(b)
    e = mb.elements.new(type="CAPSULE")
    e.co = (a + b) / 2
    e.radius = radius / REACH
    e.size_x = (b - a).length / 2
    e.rotation = Vector((1, 0, 0)).rotation_difference(b - a)
    return e


def quadruped(mb):
    ball(mb, (0, 0, 1.2), 0.5, size=(1.6, 0.8, 0.8))
    for x in (-0.6, 0.6):
        for y in (-0.22, 0.22):
            capsule(mb, (x, y, 1.1), (x, y, 0.1), 0.09)
    capsule(mb, (0.75, 0, 1.35), (1.05, 0, 1.9), 0.16)
    ball(mb, (1.2, 0, 2.0), 0.3, size=(1.3, 0.8, 0.8))
    capsule(mb, (-0.8, 0, 1.3), (-1.4, 0, 0.9), 0.06)


def eared(mb):
    ball(mb, (0, 0, 1.5), 0.55)
    ball(mb, (0, 0, 0.7), 0.45, size=(1.0, 0.8, 1.2))
    for side in (-1, 1):
        tilt = Quaternion((0, 1, 0), 0.0) @ Quaternion((1, 0, 0), 0.0)
        ball(mb, (side * 0.55, 0, 2.1), 0.4, size=(1.0, 0.18, 1.0), rotation=tilt)
        capsule(mb, (side * 0.35, 0, 0.9), (side * 0.9, 0, 0.5), 0.08)


def antlered(mb):
    ball(mb, (0, 0, 1.0), 0.45, size=(1.0, 1.2, 0.9))
    capsule(mb, (0, -0.2, 0.7), (0, -0.2, 0.0), 0.25)
    for side in (-1, 1):
        base = (side * 0.25, 0.05, 1.3)
        top = (side * 0.7, 0.1, 2.2)
        capsule(mb, base, top, 0.07)
        mid = (side * 0.45, 0.07, 1.7)
        capsule(mb, mid, (side * 0.15, 0.2, 2.1), 0.06)


def build(name, make):
    bpy.ops.wm.read_factory_settings(use_empty=True)
    data = bpy.data.metaballs.new(name)
    data.resolution = RESOLUTION
    data.render_resolution = RESOLUTION
    data.threshold = THRESHOLD
    make(data)
    ob = bpy.data.objects.new(name, data)
    bpy.context.scene.collection.objects.link(ob)
    bpy.context.view_layer.update()
    depsgraph = bpy.context.evaluated_depsgraph_get()
    mesh = bpy.data.meshes.new_from_object(ob.evaluated_get(depsgraph))
    mesh.calc_loop_triangles()
    verts = [(v.co.x, v.co.z, -v.co.y) for v in mesh.vertices]
    tris = [tuple(t.vertices) for t in mesh.loop_triangles]
    text = f"# morph held-out figure (scripts/heldout_figures.py): {name}\n"
    text += "".join("v %.6f %.6f %.6f\n" % v for v in verts)
    text += "".join("f %d %d %d\n" % (a + 1, b + 1, c + 1) for a, b, c in tris)
    return text


def write(path, text):
    if os.path.exists(path):
        # Never replace a file this script did not write the same way.
        with open(path) as f:
            if f.read() != text:
                sys.exit(f"heldout_figures: error: {path} exists and differs; choose another folder")
        return
    tmp = path + ".part"
    with open(tmp, "w") as f:
        f.write(text)
    os.replace(tmp, path)


def main():
    out = sys.argv[1] if len(sys.argv) > 1 else sys.exit(__doc__)
    os.makedirs(out, exist_ok=True)
    figures = {"quadruped": quadruped, "eared": eared, "antlered": antlered}
    for name, make in figures.items():
        write(os.path.join(out, name + ".obj"), build(name, make))
    print("wrote", ", ".join(n + ".obj" for n in figures), "into", out)


if __name__ == "__main__":
    main()

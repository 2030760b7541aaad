#!/usr/bin/env python3
"""Renders the last frames of morphs beside their target, one row per morph, in one picture
(Blender, Cycles on the CPU): the target as the run placed it, then each run's last rebuilt
frame, seen from the front (along -z), at one scale per row.

    python scripts/render_last_frames.py OUT.png NAME=DIR[,DIR...] [...] [--labels before,after]

Each DIR is a morph output folder of the same morph (its manifest names the target and how it
was placed); a relative target path is looked up from the current folder, then from DIR's
parent. Writes OUT.png through a temporary name.

Needs the `bpy` module (Blender 4.5 as a Python module, e.g. the client check's venv).
"""
import json
import math
import os
import sys

import bpy
from mathutils import Vector

TILE = 260


def target_of(out):
    m = json.load(open(os.path.join(out, "manifest.json")))
    path = m["keyframes"][-1]["target"] if m.get("keyframes") else m["inputs"][1]["path"]
    if not os.path.isabs(path) and not os.path.exists(path):
        path = os.path.join(os.path.dirname(os.path.abspath(out)), path)
    last = m["frames"][-1]["mesh"]
    return path, m["target"], os.path.join(out, last)


def place(path, scale, translation, offset):
    bpy.ops.wm.obj_import(filepath=path, forward_axis="NEGATIVE_Z", up_axis="Y")
    ob = bpy.context.selected_objects[0]
    # Blender imports Y up as Z up: the file's (x, y, z) is Blender's (x, -z, y).
    t = Vector((translation[0], -translation[2], translation[1]))
    ob.scale = (scale, scale, scale)
    ob.location = t * 1.0 + offset
    bpy.ops.object.shade_smooth()
    return ob


def main():
    args = sys.argv[1:]
    labels = ["before", "after"]
    if "--labels" in args:
        i = args.index("--labels")
        labels = args[i + 1].split(",")
        del args[i : i + 2]
    if len(args) < 2:
        sys.exit(__doc__)
    out_png, rows = args[0], [a.split("=", 1) for a in args[1:]]
    bpy.ops.wm.read_factory_settings(use_empty=True)
    scene = bpy.context.scene
    mat = bpy.data.materials.new("m")
    mat.use_nodes = True
    mat.node_tree.nodes["Principled BSDF"].inputs["Base Color"].default_value = (0.75, 0.45, 0.3, 1)
    ink = bpy.data.materials.new("ink")
    ink.diffuse_color = (0.05, 0.05, 0.05, 1)
    ink.use_nodes = True
    ink.node_tree.nodes["Principled BSDF"].inputs["Base Color"].default_value = (0.02, 0.02, 0.02, 1)
    columns = 1 + max(len(dirs.split(",")) for _, dirs in rows)
    step = 2.6
    for r, (name, dirs) in enumerate(rows):
        dirs = dirs.split(",")
        path, t, _ = target_of(dirs[0])
        obs = [place(path, t["scale"], t["translation"], Vector((0, 0, 0)))]
        for d in dirs:
            obs.append(place(target_of(d)[2], 1.0, [0, 0, 0], Vector((0, 0, 0))))
        # One scale per row: the target's box fits a tile.
        bb = [obs[0].matrix_world @ Vector(c) for c in obs[0].bound_box]
        lo = Vector([min(v[i] for v in bb) for i in range(3)])
        hi = Vector([max(v[i] for v in bb) for i in range(3)])
        s = 2.0 / max(hi - lo)
        centre = (lo + hi) / 2
        for c, ob in enumerate(obs):
            ob.scale = ob.scale * s
            ob.location = (ob.location - centre) * s + Vector((c * step, 0, -r * step))
            ob.data.materials.append(mat)
        for c, text in enumerate([name + ": target"] + labels[: len(dirs)]):
            bpy.ops.object.text_add(location=(c * step - 1.2, -1.5, -r * step + 1.1))
            label = bpy.context.object
            label.data.body = text
            label.data.size = 0.22
            label.rotation_euler = (math.pi / 2, 0, 0)
            label.data.materials.append(ink)
    cam = bpy.data.objects.new("cam", bpy.data.cameras.new("cam"))
    cam.data.type = "ORTHO"
    cam.data.ortho_scale = step * max(columns, len(rows))
    cam.location = ((columns - 1) * step / 2, -20, -(len(rows) - 1) * step / 2)
    cam.rotation_euler = (math.pi / 2, 0, 0)
    scene.collection.objects.link(cam)
    scene.camera = cam
    sun = bpy.data.objects.new("sun", bpy.data.lights.new("sun", "SUN"))
    sun.rotation_euler = (0.9, 0.2, 0.6)
    sun.data.energy = 3.0
    scene.collection.objects.link(sun)
    world = bpy.data.worlds.new("w")
    world.color = (0.85, 0.85, 0.87)
    scene.world = world
    scene.render.engine = "CYCLES"
    scene.cycles.device = "CPU"
    scene.cycles.samples = 16
    scene.render.resolution_x = TILE * columns
    scene.render.resolution_y = TILE * len(rows)
    tmp = out_png + ".part.png"
    scene.render.filepath = tmp
    bpy.ops.render.render(write_still=True)
    os.replace(tmp, out_png)


if __name__ == "__main__":
    main()

#!/usr/bin/env python3
"""Renders chosen frames of morph outputs' carried surface with Blender (bpy, Cycles on the
CPU) into one contact sheet: a row per output, a column per frame.

    python scripts/render_frames.py [--size WxH] OUT.png 5,15,30,45,60,73 LABEL=DIR[:SUB] [...]

SUB is the surface's folder in the output: `carried` (the default) or `meshes` (rebuilt).
--size sets each tile's pixels (200x160 by default; larger to see fine ripples).

Needs the `bpy` module (Blender 4.5 as a Python module, e.g. the client check's venv).
"""
import os
import sys
import tempfile

import bpy


SIZE = (200, 160)


def render(obj_path, png, size=SIZE):
    bpy.ops.wm.read_factory_settings(use_empty=True)
    bpy.ops.wm.obj_import(filepath=obj_path)
    ob = bpy.context.selected_objects[0]
    bpy.ops.object.shade_smooth()
    scene = bpy.context.scene
    scene.render.engine = "CYCLES"
    scene.cycles.device = "CPU"
    scene.cycles.samples = 16
    scene.render.resolution_x, scene.render.resolution_y = size
    scene.render.film_transparent = False
    world = bpy.data.worlds.new("w")
    world.color = (0.8, 0.8, 0.82)
    scene.world = world
    mat = bpy.data.materials.new("m")
    mat.use_nodes = True
    mat.node_tree.nodes["Principled BSDF"].inputs["Base Color"].default_value = (0.75, 0.45, 0.3, 1)
    ob.data.materials.append(mat)
    cam = bpy.data.objects.new("cam", bpy.data.cameras.new("cam"))
    scene.collection.objects.link(cam)
    scene.camera = cam
    cam.location = (0.0, -7.5, 1.5)
    cam.rotation_euler = (1.37, 0.0, 0.0)
    sun = bpy.data.objects.new("sun", bpy.data.lights.new("sun", "SUN"))
    sun.data.energy = 3.0
    sun.rotation_euler = (0.6, 0.2, 0.8)
    scene.collection.objects.link(sun)
    scene.render.filepath = png
    bpy.ops.render.render(write_still=True)


def main():
    global SIZE
    args = sys.argv[1:]
    if args[0] == "--size":
        SIZE = tuple(int(n) for n in args[1].split("x"))
        args = args[2:]
    out, frames, runs = args[0], [int(f) for f in args[1].split(",")], args[2:]
    tmp = tempfile.mkdtemp()
    tiles = []
    for r, run in enumerate(runs):
        label, folder = run.split("=", 1)
        folder, sub = folder.split(":", 1) if ":" in folder else (folder, "carried")
        row = []
        for f in frames:
            png = os.path.join(tmp, f"{r}_{f}.png")
            render(os.path.join(folder, sub, f"frame_{f:04d}.obj"), png, SIZE)
            row.append(png)
        tiles.append((label, row))
    # Paste the tiles into one image with bpy's image API.
    w, h = SIZE
    sheet = bpy.data.images.new("sheet", width=w * len(frames), height=h * len(tiles))
    pixels = [0.0] * (w * len(frames) * h * len(tiles) * 4)
    for r, (_, row) in enumerate(reversed(tiles)):
        for c, png in enumerate(row):
            img = bpy.data.images.load(png)
            px = list(img.pixels)
            for y in range(h):
                start = ((r * h + y) * w * len(frames) + c * w) * 4
                pixels[start:start + w * 4] = px[y * w * 4:(y + 1) * w * 4]
    sheet.pixels = pixels
    sheet.filepath_raw = out
    sheet.file_format = "PNG"
    sheet.save()
    print("rows:", [label for label, _ in tiles], "frames:", frames)


if __name__ == "__main__":
    main()

#!/usr/bin/env python3
"""Renders meshes coloured by their faces' angle to a reference (PLY files written by
`cargo run --release --example surface_against -- MESH REFERENCE SPACING --colour OUT.ply`:
white at 0 degrees, yellow at 10, red from 20) side by side, with Blender (bpy, Cycles on
the CPU), under one orthographic camera at a three-quarter view, so a person sees where a
surface's mean normal deviation comes from.

    python scripts/render_deviation.py OUT.png LABEL=FILE.ply [LABEL=FILE.ply ...] [--width 1400]

Writes OUT.png through a temporary name. Needs the `bpy` module (Blender 4.5 as a Python
module, e.g. the client check's venv).
"""
import argparse
import math
import os

import bpy
from mathutils import Euler, Matrix, Vector


def load_ply(path, name):
    before = set(bpy.data.objects)
    bpy.ops.wm.ply_import(filepath=path, forward_axis="NEGATIVE_Z", up_axis="Y")
    new = [o for o in bpy.data.objects if o not in before]
    if not new:
        raise SystemExit(f"render deviation: error: {path}: Blender imported nothing")
    ob = new[0]
    ob.name = name
    return ob


def coloured(name, attribute):
    mat = bpy.data.materials.new(name)
    mat.use_nodes = True
    nodes = mat.node_tree.nodes
    bsdf = nodes["Principled BSDF"]
    bsdf.inputs["Roughness"].default_value = 0.5
    colour = nodes.new("ShaderNodeAttribute")
    colour.attribute_name = attribute
    mat.node_tree.links.new(colour.outputs["Color"], bsdf.inputs["Base Color"])
    return mat


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("png")
    ap.add_argument("tiles", nargs="+")
    ap.add_argument("--width", type=int, default=1400)
    ap.add_argument("--samples", type=int, default=24)
    args = ap.parse_args()
    bpy.ops.wm.read_factory_settings(use_empty=True)
    scene = bpy.context.scene
    view = Euler((math.radians(70), 0.0, math.radians(35)), "XYZ").to_matrix()
    right, up = view @ Vector((1, 0, 0)), view @ Vector((0, 1, 0))
    tiles = []
    for c, tile in enumerate(args.tiles):
        label, path = tile.split("=", 1)
        ob = load_ply(path, f"tile{c}")
        attribute = ob.data.color_attributes[0].name if ob.data.color_attributes else "Col"
        ob.data.materials.append(coloured(f"m{c}", attribute))
        tiles.append((label, ob))
    # Each mesh scaled to one size (the runs' units differ), then moved onto a row in the
    # camera's plane.
    bpy.context.view_layer.update()
    for _, ob in tiles:
        corners = [Vector(c) for c in ob.bound_box]
        diagonal = (corners[6] - corners[0]).length
        ob.matrix_world = Matrix.Scale(1.0 / diagonal, 4) @ ob.matrix_world
    bpy.context.view_layer.update()
    size, centre = 0.0, {}
    for _, ob in tiles:
        corners = [ob.matrix_world @ Vector(c) for c in ob.bound_box]
        size = max(size, max((a - b).length for a in corners for b in corners))
        centre[ob.name] = sum(corners, Vector()) / 8
    cell = 1.05 * size
    for c, (_, ob) in enumerate(tiles):
        ob.matrix_world = Matrix.Translation(c * cell * right - centre[ob.name]) @ ob.matrix_world

    ink = bpy.data.materials.new("ink")
    ink.use_nodes = True
    ink.node_tree.nodes["Principled BSDF"].inputs["Base Color"].default_value = (0.05, 0.05, 0.05, 1)
    for c, (label, _) in enumerate(tiles):
        curve = bpy.data.curves.new(label, "FONT")
        curve.body = label
        curve.align_x = "CENTER"
        curve.size = 0.07 * cell
        t = bpy.data.objects.new(label, curve)
        t.matrix_world = Matrix.Translation(c * cell * right + 0.55 * cell * up) @ view.to_4x4()
        t.data.materials.append(ink)
        scene.collection.objects.link(t)

    cam = bpy.data.objects.new("cam", bpy.data.cameras.new("cam"))
    cam.data.type = "ORTHO"
    width, height = (len(tiles) + 0.1) * cell, 1.3 * cell
    cam.data.ortho_scale = max(width, height)
    mid = (len(tiles) - 1) / 2 * cell * right + 0.1 * cell * up
    cam.matrix_world = Matrix.Translation(mid + 20 * size * (view @ Vector((0, 0, 1)))) @ view.to_4x4()
    cam.data.clip_end = 100 * size
    scene.collection.objects.link(cam)
    scene.camera = cam
    sun = bpy.data.objects.new("sun", bpy.data.lights.new("sun", "SUN"))
    sun.data.energy = 3.5
    sun.matrix_world = (view @ Euler((math.radians(-30), math.radians(25), 0), "XYZ").to_matrix()).to_4x4()
    scene.collection.objects.link(sun)
    world = bpy.data.worlds.new("w")
    world.color = (0.42, 0.43, 0.46)
    scene.world = world
    scene.render.engine = "CYCLES"
    scene.cycles.device = "CPU"
    scene.cycles.samples = args.samples
    scene.render.resolution_x = args.width
    scene.render.resolution_y = int(args.width * height / width)
    scene.render.image_settings.file_format = "PNG"
    scene.render.image_settings.color_mode = "RGB"
    scene.render.image_settings.compression = 100
    partial = args.png + ".part.png"
    scene.render.filepath = partial
    bpy.ops.render.render(write_still=True)
    os.replace(partial, args.png)
    print(f"render deviation: {args.png}: {[label for label, _ in tiles]}")


if __name__ == "__main__":
    main()

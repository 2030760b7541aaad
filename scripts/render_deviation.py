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
import sys

import bpy
from mathutils import Euler, Matrix, Vector

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from contact_sheet import caption, render  # noqa: E402  (the contact sheet's camera and light)


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

    for c, (text, _) in enumerate(tiles):
        caption(scene, view, text, c * cell * right + 0.55 * cell * up, 0.07 * cell)
    extent = ((len(tiles) + 0.1) * cell, 1.3 * cell)
    mid = (len(tiles) - 1) / 2 * cell * right + 0.1 * cell * up
    render(scene, view, mid, extent, size, args.width, args.samples, 3.5, args.png)
    print(f"render deviation: {args.png}: {[text for text, _ in tiles]}")


if __name__ == "__main__":
    main()

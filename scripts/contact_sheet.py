#!/usr/bin/env python3
"""Renders a morph output's contact sheet with Blender (bpy, Cycles on the CPU): the carried
and the rebuilt surface (and the volume, with --volume) on frame 1, the middle of the way, the arrival frame and the last
frame, and the target as the run placed it, in one picture a person can look at.

    python scripts/contact_sheet.py OUT [--png PATH] [--frames 1,30,59,73] [--width 1400]

Writes OUT/contact.png unless --png says where (written to a temporary name, then renamed).
A file in OUT that morph did not write makes `morph --overwrite` and `--resume` refuse OUT
until it is moved away: give --png a path outside OUT where OUT will be run again.
The frames default to 1, the first keyframe's halfway frame, the last keyframe's arrival
frame and the last frame, read from OUT/manifest.json, as are the surfaces' files. The target
is the last keyframe's mesh, placed by the manifest's `target` map; a relative path is looked
up from the current folder, then from OUT's parent. A surface the run did not write leaves its row out.

Everything is one Blender scene: each tile is a copy of its mesh moved onto a grid in the
camera's plane, under one orthographic camera, so the tiles share a scale and a light and
one render makes the sheet (with its labels, Blender text objects).

Needs the `bpy` module (Blender 4.5 as a Python module, e.g. the client check's venv).
"""
import argparse
import json
import math
import os
import sys

import bpy
from mathutils import Euler, Matrix, Vector


def load_obj(path, name):
    """Imports an OBJ as one object named `name` (Blender's importer, as an artist would)."""
    before = set(bpy.data.objects)
    bpy.ops.wm.obj_import(filepath=path, forward_axis="NEGATIVE_Z", up_axis="Y")
    new = [o for o in bpy.data.objects if o not in before]
    if not new:
        raise SystemExit(f"contact sheet: error: {path}: Blender imported nothing")
    ob = new[0]
    ob.name = name
    for poly in ob.data.polygons:
        poly.use_smooth = True
    return ob


def material(name, rgb):
    mat = bpy.data.materials.new(name)
    mat.use_nodes = True
    bsdf = mat.node_tree.nodes["Principled BSDF"]
    bsdf.inputs["Base Color"].default_value = (*rgb, 1.0)
    bsdf.inputs["Roughness"].default_value = 0.45
    return mat


def volume_file(frame):
    """A frame's volume (--volume): volumes/frame_NNNN.vdb, named as its points."""
    return frame["points"].replace("frames/", "volumes/").replace(".ply", ".vdb")


def load_volume(path, name):
    """Imports a frame's OpenVDB file as a volume object, turned from morph's Y up to
    Blender's Z up (as the OBJ importer turns the surfaces)."""
    bpy.ops.object.volume_import(filepath=path)
    ob = bpy.context.selected_objects[0]
    ob.name = name
    ob.data.grids.load()
    ob.matrix_world = Matrix.Rotation(math.pi / 2, 4, "X")
    # A new material's default nodes follow the active object's type: not a volume's.
    bpy.context.view_layer.objects.active = None
    return ob


def volume_material():
    """The fill field as smoke: density from the grid, a warm tone."""
    mat = bpy.data.materials.new("volume")
    mat.use_nodes = True
    nodes = mat.node_tree.nodes
    nodes.clear()
    shader = nodes.new("ShaderNodeVolumePrincipled")
    shader.inputs["Color"].default_value = (0.85, 0.55, 0.35, 1)
    shader.inputs["Density"].default_value = 12.0
    output = nodes.new("ShaderNodeOutputMaterial")
    mat.node_tree.links.new(shader.outputs[0], output.inputs["Volume"])
    return mat


def resolve(path, out):
    if os.path.isabs(path) and os.path.exists(path):
        return path
    for base in (os.getcwd(), os.path.dirname(os.path.abspath(out))):
        p = os.path.join(base, path)
        if os.path.exists(p):
            return p
    return None


def caption(scene, view, body, at, scale):
    """A text object `body` centred at `at`, facing the camera's `view`."""
    curve = bpy.data.curves.new(body, "FONT")
    curve.body = body
    curve.align_x = "CENTER"
    curve.size = scale
    t = bpy.data.objects.new(body, curve)
    t.matrix_world = Matrix.Translation(at) @ view.to_4x4()
    t.data.materials.append(material("ink", (0.05, 0.05, 0.05)))
    scene.collection.objects.link(t)


def render(scene, view, mid, extent, size, width_px, samples, sun_energy, png):
    """Renders `scene` under one orthographic camera looking along `view` at `mid`, framing
    `extent` (width, height) in scene units (`size`: the largest object's, for the clipping),
    with a sun and a grey world, Cycles on the CPU, into `png` through a temporary name."""
    width, height = extent
    cam = bpy.data.objects.new("cam", bpy.data.cameras.new("cam"))
    cam.data.type = "ORTHO"
    cam.data.ortho_scale = max(width, height)
    back = view @ Vector((0, 0, 1))
    cam.matrix_world = Matrix.Translation(mid + 20 * size * back) @ view.to_4x4()
    cam.data.clip_end = 100 * size
    scene.collection.objects.link(cam)
    scene.camera = cam
    sun = bpy.data.objects.new("sun", bpy.data.lights.new("sun", "SUN"))
    sun.data.energy = sun_energy
    sun.matrix_world = (view @ Euler((math.radians(-30), math.radians(25), 0), "XYZ").to_matrix()).to_4x4()
    scene.collection.objects.link(sun)
    world = bpy.data.worlds.new("w")
    world.color = (0.42, 0.43, 0.46)
    scene.world = world
    scene.render.engine = "CYCLES"
    scene.cycles.device = "CPU"
    scene.cycles.samples = samples
    scene.render.resolution_x = width_px
    scene.render.resolution_y = int(width_px * height / width)
    scene.render.image_settings.file_format = "PNG"
    scene.render.image_settings.color_mode = "RGB"
    scene.render.image_settings.compression = 100
    partial = png + ".part.png"
    scene.render.filepath = partial
    bpy.ops.render.render(write_still=True)
    os.replace(partial, png)


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("out")
    ap.add_argument("--png")
    ap.add_argument("--frames")
    ap.add_argument("--width", type=int, default=1400)
    ap.add_argument("--samples", type=int, default=24)
    args = ap.parse_args(sys.argv[sys.argv.index("--") + 1:] if "--" in sys.argv else None)
    out = args.out
    try:
        with open(os.path.join(out, "manifest.json")) as f:
            manifest = json.load(f)
        manifest["frames"]
    except (OSError, ValueError, KeyError, TypeError) as e:
        raise SystemExit(f"contact sheet: error: {out}: not a finished morph output ({e})")
    last = len(manifest["frames"])
    keys = manifest.get("keyframes") or []
    if args.frames:
        frames = [int(f) for f in args.frames.split(",")]
    else:
        halfway = keys[0].get("halfway_frame", last // 2) if keys else last // 2
        arrival = keys[-1].get("frame", last) if keys else last
        frames = sorted({1, halfway, arrival, last})
    names = {1: "frame 1", last: f"last ({last})"}
    if keys:
        names.setdefault(keys[-1].get("frame"), f"arrival ({keys[-1].get('frame')})")
        names.setdefault(keys[0].get("halfway_frame"), f"halfway ({keys[0].get('halfway_frame')})")

    bpy.ops.wm.read_factory_settings(use_empty=True)
    scene = bpy.context.scene
    rows = []
    # Each row's files as the manifest lists them per frame (a volume is named as its points).
    for label, key, rgb in (("carried", "carried_mesh", (0.78, 0.47, 0.32)),
                            ("rebuilt", "mesh", (0.35, 0.55, 0.78))):
        if manifest["frames"] and manifest["frames"][0].get(key):
            rows.append((label, lambda frame, key=key: frame[key], material(label, rgb)))
    if manifest.get("settings", {}).get("volume"):
        rows.append(("volume", volume_file, volume_material()))
    if not rows:
        raise SystemExit(f"contact sheet: error: {out}: the run wrote no surfaces (--no-surfaces)")

    tiles = []  # (object, row, column)
    for r, (label, file_of, mat) in enumerate(rows):
        for c, f in enumerate(frames):
            if not 1 <= f <= last:
                raise SystemExit(f"contact sheet: error: frame {f} is not in 1..{last}")
            path = os.path.join(out, file_of(manifest["frames"][f - 1]))
            if not os.path.exists(path):
                raise SystemExit(f"contact sheet: error: {path}: missing")
            ob = (load_volume if label == "volume" else load_obj)(path, f"{label}_{f}")
            ob.data.materials.clear()
            ob.data.materials.append(mat)
            tiles.append((ob, r, c))
    target = None
    if keys:
        path = resolve(keys[-1]["target"], out)
        place = manifest.get("target")
        if path and place:
            target = load_obj(path, "target")
            s, t = place["scale"], place["translation"]
            # The map is in the file's axes; the importer turned Y-up into Z-up.
            to_blender = Matrix.Rotation(math.pi / 2, 4, "X")
            target.matrix_world = to_blender @ Matrix.Translation(Vector(t)) @ Matrix.Scale(s, 4)
            target.data.materials.append(material("target", (0.55, 0.6, 0.5)))
            tiles.append((target, (len(rows) - 1) / 2, len(frames)))

    # One camera at a three-quarter view; each tile is moved in the camera's plane so that
    # every copy is seen from the same angle.
    view = Euler((math.radians(70), 0.0, math.radians(35)), "XYZ").to_matrix()
    right, up = view @ Vector((1, 0, 0)), view @ Vector((0, 1, 0))
    size = 0.0
    for ob, _, _ in tiles:
        bpy.context.view_layer.update()
        corners = [ob.matrix_world @ Vector(c) for c in ob.bound_box]
        size = max(size, max((a - b).length for a in corners for b in corners))
    cell = 1.05 * size
    centre = {}
    for ob, _, _ in tiles:
        corners = [ob.matrix_world @ Vector(c) for c in ob.bound_box]
        centre[ob.name] = sum(corners, Vector()) / 8
    columns = len(frames) + (1 if target else 0)
    header = 0.25 * cell
    for ob, r, c in tiles:
        goal = (c * cell) * right - (r * cell) * up
        ob.matrix_world = Matrix.Translation(goal - centre[ob.name]) @ ob.matrix_world

    def text(body, at, scale):
        caption(scene, view, body, at, scale)

    for c, f in enumerate(frames):
        text(names.get(f, f"frame {f}"), c * cell * right + 0.55 * cell * up, 0.09 * cell)
    if target:
        text("target", len(frames) * cell * right + 0.55 * cell * up, 0.09 * cell)
    for r, (label, _, _) in enumerate(rows):
        text(label, -0.62 * cell * right - r * cell * up, 0.09 * cell)

    width = (columns + 0.5) * cell
    height = (len(rows) * cell + header)
    mid = ((columns - 1) / 2 - 0.25) * cell * right - ((len(rows) - 1) / 2 - 0.12) * cell * up
    png = args.png or os.path.join(out, "contact.png")
    render(scene, view, mid, (width, height), size, args.width, args.samples, 4.5, png)
    print(f"contact sheet: {png}: rows {[r[0] for r in rows]}, frames {frames}"
          + (", target" if target else ""))


if __name__ == "__main__":
    main()

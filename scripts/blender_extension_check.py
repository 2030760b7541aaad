"""Installs the morph Blender extension from its zip into headless Blender 4.5 (bpy), makes a
UV sphere and a cube, runs "Morph to target" on them, and checks what comes back: the imported
objects, the frame range, the fps, the particles' velocity attribute, the carried mesh's UV map
and the motion blur. Run by scripts/python-check.sh:

    python scripts/blender_extension_check.py EXTENSION.zip WORKDIR
"""
import json
import sys
from pathlib import Path

import bpy

zip_path, work = Path(sys.argv[-2]), Path(sys.argv[-1])
failures = []


def check(what, ok, detail=""):
    print(f"{'ok  ' if ok else 'FAIL'} {what}{': ' + str(detail) if detail != '' else ''}")
    if not ok:
        failures.append(what)


bpy.ops.wm.read_factory_settings(use_empty=True)
bpy.ops.extensions.package_install_files(filepath=str(zip_path), repo="user_default",
                                         enable_on_install=True)
check("extension installed and enabled", hasattr(bpy.ops.morph, "morph_to_target")
      and hasattr(bpy.types.Scene, "morph"))

bpy.ops.mesh.primitive_uv_sphere_add(radius=1.0, location=(0, 0, 0))
sphere = bpy.context.active_object
sphere.name = "Sphere"
bpy.ops.mesh.primitive_cube_add(size=1.8, location=(0, 0, 0))
cube = bpy.context.active_object
cube.name = "Cube"
for o in bpy.context.scene.objects:
    o.select_set(True)
bpy.context.view_layer.objects.active = sphere

settings = bpy.context.scene.morph
# The default output is relative to the .blend file, which is not saved yet: refused.
try:
    bpy.ops.morph.morph_to_target()
    check("an output relative to an unsaved .blend is refused", False, "no error")
except RuntimeError as e:
    check("an output relative to an unsaved .blend is refused", "save the .blend" in str(e), str(e).strip())
settings.preset = "draft"
settings.frames = 25
settings.arrival = 20
settings.begin = 7
settings.output = str(work / "morph")
result = bpy.ops.morph.morph_to_target()
check("operator finished", result == {"FINISHED"}, result)

scene = bpy.context.scene
manifest = json.loads((work / "morph" / "manifest.json").read_text())
speeds = [f["rms_speed"] for f in manifest["frames"]]
check("the change begins on the panel's begin frame: still before it, moving after",
      manifest["settings"]["shot"]["begin"] == 7 and all(s == 0 for s in speeds[:7]) and speeds[7] > 0
      and manifest["motion"]["first_frame"] == 7, (manifest["settings"]["shot"]["begin"], speeds[:9]))
objects = {o.name: o for o in scene.objects}
print("     objects:", sorted(objects))
check("imported particles, carried and rebuilt objects",
      all(n in objects for n in ("particles", "carried", "rebuilt")), sorted(objects))
check("frame range = the morph's frames", (scene.frame_start, scene.frame_end) == (1, 25),
      (scene.frame_start, scene.frame_end))
check("fps = the morph's", abs(scene.render.fps / scene.render.fps_base - manifest["fps"]) < 1e-6,
      scene.render.fps)
check("motion blur on", scene.render.use_motion_blur)
scene.frame_set(20)
depsgraph = bpy.context.evaluated_depsgraph_get()
if "particles" in objects:
    data = objects["particles"].evaluated_get(depsgraph).data
    names = [a.name for a in data.attributes]
    check("particles: a velocity attribute", "velocity" in names, names)
if "carried" in objects:
    mesh = objects["carried"].evaluated_get(depsgraph).data
    check("carried mesh: the source's UV map", len(mesh.uv_layers) >= 1 and len(mesh.vertices) == len(sphere.data.vertices),
          ([u.name for u in mesh.uv_layers], len(mesh.vertices), len(sphere.data.vertices)))
    xs = [v.co for v in mesh.vertices]
    extent = [max(p[i] for p in xs) - min(p[i] for p in xs) for i in range(3)]
    check("carried mesh at the arrival frame: about the cube's size (1.8)", all(1.4 < e < 2.3 for e in extent), extent)

# A file the add-on did not write is never replaced: a user's own source.obj where the
# add-on would put its input files.
guarded = work / "guarded-inputs"
guarded.mkdir()
(guarded / "source.obj").write_text("# the user's own file\n")
settings.output = str(work / "guarded")
try:
    bpy.ops.morph.morph_to_target()
    check("a file the add-on did not write is refused", False, "no error")
except RuntimeError as e:
    check("a file the add-on did not write is refused, and kept",
          "not one of the add-on's input files" in str(e)
          and (guarded / "source.obj").read_text() == "# the user's own file\n", str(e).strip())

# An error is a report, never a traceback: a source with no volume.
bpy.ops.mesh.primitive_plane_add()
plane = bpy.context.active_object
cube.select_set(True)
settings.output = str(work / "bad")
try:
    bpy.ops.morph.morph_to_target()
    check("a flat source is refused", False, "no error")
except RuntimeError as e:  # bpy raises an operator's ERROR report as RuntimeError
    check("a flat source is refused with morph's one-line message", "morph: " in str(e), str(e).strip())

print(f"blender extension: {len(failures)} failed")
sys.exit(1 if failures else 0)

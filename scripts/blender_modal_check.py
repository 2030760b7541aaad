"""The operator's interactive path, which headless `bpy` cannot run (no event loop): in a
Blender binary with a window (Xvfb), "Morph to target" is invoked as a click would, and the
interface's own timers must keep ticking while the morph runs in its thread. Needs the
module's files on a path (an unpacked wheel) and a saved .blend (no splash):

    python3 -c "import zipfile,sys; zipfile.ZipFile(sys.argv[1]).extractall(sys.argv[2])" WHEEL SITE
    xvfb-run -a blender START.blend --python scripts/blender_modal_check.py -- SITE OUT

Prints how many 0.5 s interface ticks passed while it ran, then quits. With
MORPH_MODAL_SHOT=PNG it also takes a screenshot of the window six seconds in. (Run by hand, with
Debian's Blender 3.4, which has no USD importer: the operator then reports that it cannot
import the result, as it should, and the folder is complete.)
"""
import os
import sys
import time
from pathlib import Path

import bpy

site, out = sys.argv[-2], sys.argv[-1]
sys.path.insert(0, site)
sys.path.insert(0, str(Path(__file__).resolve().parent.parent / "blender"))
import morph_blender  # noqa: E402

morph_blender.register()
scene = bpy.context.scene
for o in scene.objects:  # the start file's own selection
    o.select_set(False)
bpy.ops.mesh.primitive_cube_add(size=1.8)
cube = bpy.context.active_object
bpy.ops.mesh.primitive_uv_sphere_add(radius=1.0)
sphere = bpy.context.active_object
cube.select_set(True)
sphere.select_set(True)
bpy.context.view_layer.objects.active = sphere
scene.morph.preset = "draft"
scene.morph.frames = 13
scene.morph.output = out
ticks = []
start = time.time()


def invoke():
    for window in bpy.context.window_manager.windows:
        for area in window.screen.areas:
            if area.type == "VIEW_3D":
                with bpy.context.temp_override(window=window, area=area):
                    print("invoke:", bpy.ops.morph.morph_to_target("INVOKE_DEFAULT"), flush=True)
    bpy.app.timers.register(watch, first_interval=0.5)


def watch():
    ticks.append(time.time())
    if len(ticks) == 12 and os.environ.get("MORPH_MODAL_SHOT"):
        # The window while the morph runs: its progress in the status bar.
        bpy.ops.screen.screenshot(filepath=os.environ["MORPH_MODAL_SHOT"])
    done = os.path.exists(os.path.join(out, "manifest.json"))
    if done or time.time() - start > 300:
        print(f"{'ok  ' if done and len(ticks) > 4 else 'FAIL'} the interface ticked {len(ticks)} "
              f"times in {time.time() - start:.1f} s while the morph ran", flush=True)
        bpy.app.timers.register(quit_blender, first_interval=2.0)
        return None
    return 0.5


def quit_blender():
    bpy.ops.wm.quit_blender()
    return None


bpy.app.timers.register(invoke, first_interval=1.0)

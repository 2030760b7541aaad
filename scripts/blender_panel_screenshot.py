"""Screenshot of the Morph panel in Blender's 3D view sidebar, for the README
(docs/images/blender-panel.png). Needs a Blender binary and an X server (Xvfb):

    blender -b --factory-startup --python-expr "import bpy; bpy.ops.wm.save_as_mainfile(filepath='/tmp/start.blend')"
    xvfb-run -a -s "-screen 0 1600x900x24" blender /tmp/start.blend --python scripts/blender_panel_screenshot.py -- OUT.png

(a saved file opens without the splash screen). The picture in the README was taken with
Debian's Blender 3.4 (`apt install blender xvfb`): Blender 4.5 is a Python module only here
(PyPI's bpy, no interface) and its binary could not be downloaded. 3.4 draws the same panel
code, but cannot pick the sidebar's tab from Python, so the panel is shown in the open tab.
"""
import sys
from pathlib import Path

import bpy
sys.path.insert(0, str(Path(__file__).resolve().parent.parent / "blender"))
import morph_blender
# Blender 3.4 cannot switch the sidebar's tab from Python (Region.active_panel_category came
# later): for the picture, the panel goes in the tab that is open, Item.
morph_blender.MORPH_PT_panel.bl_category = "Item"
morph_blender.register()

out = sys.argv[-1]
scene = bpy.context.scene
cube = bpy.data.objects.get("Cube")
bpy.ops.mesh.primitive_uv_sphere_add(radius=0.8, location=(0, 0, 2.2))
sphere = bpy.context.active_object
sphere.name = "Sphere"
cube.name = "Cube"
for o in scene.objects:
    o.select_set(o in (cube, sphere))
bpy.context.view_layer.objects.active = sphere
scene.morph.preset = "draft"
scene.morph.frames = 73
scene.morph.arrival = 59
scene.morph.output = "//morph_sphere_bunny"


def shoot():
    for window in bpy.context.window_manager.windows:
        for area in window.screen.areas:
            if area.type == "VIEW_3D":
                area.spaces.active.show_region_ui = True
                region = next(r for r in area.regions if r.type == "WINDOW")
                with bpy.context.temp_override(window=window, area=area, region=region):
                    bpy.ops.view3d.view_selected()
    bpy.app.timers.register(take, first_interval=1.5)


def take():
    for window in bpy.context.window_manager.windows:
        for area in window.screen.areas:
            if area.type == "VIEW_3D":
                with bpy.context.temp_override(window=window, area=area):
                    bpy.ops.screen.screenshot_area(filepath=out)
    bpy.ops.wm.quit_blender()


bpy.app.timers.register(shoot, first_interval=2.0)

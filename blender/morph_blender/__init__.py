"""Morph to target: the active object becomes the other selected object(s), simulated by
morph (an elastic body whose deformation is optimized to flow into each target in turn).

The meshes are written as OBJ files (world space, Y up, with their UVs) beside the output
folder (`OUT-inputs/`: the morph never takes an input from inside its output), the morph runs in a thread while a modal timer shows its progress (Esc
cancels), and the result comes back through its USD file: particles with velocities, the
carried surface with the source's UVs, the rebuilt surface; the scene takes its frame range
and frame rate, and motion blur is turned on. In background mode (no event loop for timers)
the operator runs the morph to the end before it returns.
"""

import os
import threading
from pathlib import Path

import bpy
from bpy.props import BoolProperty, EnumProperty, IntProperty, PointerProperty, StringProperty

PRESETS = [
    ("draft", "Draft", "A quick look (about 10 s for the built-in assets)"),
    ("default", "Default", "The shipped quality (about a minute)"),
    ("final", "Final", "More detail and passes (several minutes)"),
]


class MorphSettings(bpy.types.PropertyGroup):
    preset: EnumProperty(name="Preset", items=PRESETS, default="default")
    frames: IntProperty(name="Frames", description="Frames in the sequence, the rest shape first "
                        "(0: the preset's)", default=0, min=0, max=100000)
    arrival: IntProperty(name="Arrival frame", description="The frame by which the last target is "
                         "reached (0: 80% of the frames)", default=0, min=0, max=100000)
    begin: IntProperty(name="Begin frame", description="The frame the shape change begins on; before "
                       "it the body holds still or falls on its own (1: the first frame)", default=1,
                       min=1, max=100000)
    output: StringProperty(name="Output", subtype="DIR_PATH", default="//morph",
                           description="The morph's output folder (frames, surfaces, morph.usdc)")
    overwrite: BoolProperty(name="Overwrite", default=False,
                            description="Replace an earlier morph's output folder")


# The first line of every OBJ this add-on writes: a file without it is never replaced.
MARKER = "# written by the morph Blender extension"


def write_obj(obj, path, depsgraph):
    """`obj`'s evaluated mesh in world space as an OBJ, Y up (morph's convention), with its
    active UV map. An existing file at `path` is replaced only if this add-on wrote it."""
    if path.exists():
        with open(path, errors="replace") as f:
            if f.readline().rstrip("\n") != MARKER:
                raise OSError(f"'{path}' exists and is not one of the add-on's input files; "
                              "move it, or choose another output folder")
    evaluated = obj.evaluated_get(depsgraph)
    mesh = evaluated.to_mesh()
    try:
        mesh.transform(obj.matrix_world)
        mesh.calc_loop_triangles()
        uv = mesh.uv_layers.active
        tmp = path.with_name(path.name + ".tmp")
        with open(tmp, "w") as f:
            f.write(f"{MARKER}\n# {obj.name}, from Blender (Y up)\n")
            for v in mesh.vertices:
                x, y, z = v.co
                f.write(f"v {x:.9g} {z:.9g} {-y:.9g}\n")
            if uv is not None:
                for tri in mesh.loop_triangles:
                    for loop in tri.loops:
                        u, w = uv.data[loop].uv
                        f.write(f"vt {u:.9g} {w:.9g}\n")
            for i, tri in enumerate(mesh.loop_triangles):
                a, b, c = (k + 1 for k in tri.vertices)
                if uv is not None:
                    t = 3 * i + 1
                    f.write(f"f {a}/{t} {b}/{t + 1} {c}/{t + 2}\n")
                else:
                    f.write(f"f {a} {b} {c}\n")
        os.replace(tmp, path)  # complete, or not there at all
    finally:
        evaluated.to_mesh_clear()


class MORPH_OT_morph_to_target(bpy.types.Operator):
    """Morph the active object into the other selected object(s), in selection order by name"""
    bl_idname = "morph.morph_to_target"
    bl_label = "Morph to target"
    bl_options = {"REGISTER"}

    _timer = None
    _thread = None

    @classmethod
    def poll(cls, context):
        active = context.active_object
        others = [o for o in context.selected_objects if o is not active and o.type == "MESH"]
        return active is not None and active.type == "MESH" and len(others) >= 1

    def prepare(self, context):
        settings = context.scene.morph
        if settings.output.startswith("//") and not bpy.data.filepath:
            # A path relative to the .blend file means nothing before it is saved.
            raise OSError("save the .blend file first, or give an absolute output folder")
        out = Path(bpy.path.abspath(settings.output)).resolve()
        inputs = out.parent / f"{out.name}-inputs"
        inputs.mkdir(parents=True, exist_ok=True)
        depsgraph = context.evaluated_depsgraph_get()
        source = context.active_object
        targets = sorted((o for o in context.selected_objects if o is not source and o.type == "MESH"),
                         key=lambda o: o.name)
        write_obj(source, inputs / "source.obj", depsgraph)
        paths = []
        for i, t in enumerate(targets):
            write_obj(t, inputs / f"target_{i + 1}.obj", depsgraph)
            paths.append(inputs / f"target_{i + 1}.obj")
        kwargs = {"preset": settings.preset}
        if settings.frames:
            kwargs["frames"] = settings.frames
        if settings.arrival and len(paths) == 1:
            # Several targets are spread over the shot (morph's default).
            kwargs["at"] = [settings.arrival]
        if settings.begin > 1:
            kwargs["begin"] = settings.begin
        self.job = dict(source=inputs / "source.obj", targets=paths, out=out,
                        overwrite=settings.overwrite, **kwargs)
        self.progress = {"done": 0.0, "message": "starting", "result": None, "error": None}
        self.cancel = False

    def run_morph(self):
        import morph

        def on_event(event):
            if event["event"] == "setup":
                self.progress["message"] = f"{event['particles']} particles"
            elif event["event"] == "level":
                self.progress["message"] = f"level {event['level']} of {event['levels']}"
            self.progress["done"] = event["progress"]
            return not self.cancel

        try:
            self.progress["result"] = morph.run(on_event=on_event, **self.job)
        except morph.Cancelled:
            self.progress["error"] = "cancelled"
        except morph.MorphError as e:
            self.progress["error"] = str(e)
        except Exception as e:  # a report, never a traceback
            self.progress["error"] = f"{type(e).__name__}: {e}"

    def finish(self, context):
        error = self.progress["error"]
        if error is not None:
            self.report({"ERROR"} if error != "cancelled" else {"WARNING"}, f"morph: {error}")
            return {"CANCELLED"}
        result = self.progress["result"]
        try:
            bpy.ops.wm.usd_import(filepath=str(result.out / "morph.usdc"), set_frame_range=True)
        except (RuntimeError, AttributeError) as e:
            # AttributeError: a Blender built without USD has no importer.
            self.report({"ERROR"}, f"morph: cannot import {result.out / 'morph.usdc'} ({e}); "
                        "the frames are in that folder")
            return {"CANCELLED"}
        context.scene.render.use_motion_blur = True
        q = result.quality.get("fill")
        self.report({"INFO"}, f"morph: {len(result.manifest['frames'])} frames in {result.out}"
                    + (f", fill {q:.2f}" if q is not None else ""))
        return {"FINISHED"}

    def execute(self, context):
        try:
            self.prepare(context)
        except OSError as e:
            self.report({"ERROR"}, f"morph: {e}")
            return {"CANCELLED"}
        self.run_morph()
        return self.finish(context)

    def invoke(self, context, event):
        if bpy.app.background:
            return self.execute(context)
        try:
            self.prepare(context)
        except OSError as e:
            self.report({"ERROR"}, f"morph: {e}")
            return {"CANCELLED"}
        self._thread = threading.Thread(target=self.run_morph, daemon=True)
        self._thread.start()
        wm = context.window_manager
        self._timer = wm.event_timer_add(0.25, window=context.window)
        wm.progress_begin(0, 1)
        wm.modal_handler_add(self)
        return {"RUNNING_MODAL"}

    def modal(self, context, event):
        if event.type == "ESC":
            self.cancel = True
        if event.type != "TIMER":
            return {"PASS_THROUGH"}
        wm = context.window_manager
        wm.progress_update(self.progress["done"])
        context.workspace.status_text_set(
            f"Morph: {self.progress['message']}, {100 * self.progress['done']:.0f}%"
            + (" (cancelling)" if self.cancel else " (Esc to cancel)"))
        if self._thread.is_alive():
            return {"RUNNING_MODAL"}
        wm.event_timer_remove(self._timer)
        wm.progress_end()
        context.workspace.status_text_set(None)
        return self.finish(context)


class MORPH_PT_panel(bpy.types.Panel):
    bl_label = "Morph"
    bl_idname = "MORPH_PT_panel"
    bl_space_type = "VIEW_3D"
    bl_region_type = "UI"
    bl_category = "Morph"

    def draw(self, context):
        layout = self.layout
        settings = context.scene.morph
        active = context.active_object
        targets = [o.name for o in context.selected_objects if o is not active and o.type == "MESH"]
        col = layout.column()
        col.label(text=f"Source: {active.name if active else '-'}", icon="MESH_DATA")
        col.label(text=f"Targets: {', '.join(sorted(targets)) or 'select one or more'}", icon="FORWARD")
        layout.prop(settings, "preset")
        layout.prop(settings, "frames")
        layout.prop(settings, "arrival")
        layout.prop(settings, "begin")
        layout.prop(settings, "output")
        layout.prop(settings, "overwrite")
        layout.operator(MORPH_OT_morph_to_target.bl_idname, icon="MOD_PHYSICS")


CLASSES = (MorphSettings, MORPH_OT_morph_to_target, MORPH_PT_panel)


def register():
    for c in CLASSES:
        bpy.utils.register_class(c)
    bpy.types.Scene.morph = PointerProperty(type=MorphSettings)


def unregister():
    del bpy.types.Scene.morph
    for c in reversed(CLASSES):
        bpy.utils.unregister_class(c)

#!/usr/bin/env python3
"""Opens a morph output folder with the tools studios use, and checks what they read back.

    python scripts/check_clients.py OUT

OUT is a folder written by `morph SOURCE TARGET -o OUT`; the checks of a surface the run did not
write (`--surface carried|rebuilt|none`) are skipped and say so. Needs the PyPI packages `usd-core` (Pixar's USD) and `bpy` (Blender 4.5 as a module);
`.ci/run` installs both into a cached venv and runs this on a small morph.

Checks, each printed with what was read:
- USD (pxr), `morph.usdc` (or `morph.usda`): the stage's time codes, frame rate, up axis and
  units; the particles' points, velocities and J primvar per frame, bit for bit the PLY
  frames' float32, and their ids; the carried mesh's topology and UVs against the
  source; the rebuilt mesh's points; and Pixar's validators (what `usdchecker` runs) report no
  error.
- With --volume: the USD's Volume prim reads each frame's volumes/frame_NNNN.vdb (usd-core),
  Blender imports it as a volume object, and a frame's VDB as a volume around its surface.
- Blender (bpy): imports the USD file and reads back the frame range, fps, point count, the
  velocity attribute, the carried mesh's vertex count and UV layer; imports a carried OBJ, a
  rebuilt OBJ and a PLY frame and reads their vertex counts, UVs and attributes.
Exits 1 with the first failed check.
"""

import json
import sys
from pathlib import Path

failures = []
passed = []


def check(what, ok, detail=""):
    print(f"{'ok  ' if ok else 'FAIL'} {what}{': ' + str(detail) if detail != '' else ''}")
    (passed if ok else failures).append(what)


def obj_counts(path):
    v = vt = f = 0
    for line in open(path):
        if line.startswith("v "):
            v += 1
        elif line.startswith("vt "):
            vt += 1
        elif line.startswith("f "):
            f += 1
    return v, vt, f


def mgrid_header(path):
    """The JSON header of a .mgrid file (after its 8-byte magic and 4-byte length)."""
    raw = path.read_bytes()
    n = int.from_bytes(raw[8:12], "little")
    return json.loads(raw[12:12 + n])


def frame_range(manifest):
    """The first and last frame numbers (`--start-frame`, 1 by default)."""
    first = manifest["settings"]["shot"].get("start_frame", 1)
    return first, first + len(manifest["frames"]) - 1


def usd_file(out):
    """The run's USD file: binary `morph.usdc` (the default) or text `morph.usda` (--usd usda)."""
    binary = out / "morph.usdc"
    return binary if binary.exists() else out / "morph.usda"


def ply_frame(path):
    """A frame PLY's float32 columns (x y z vx vy vz J) as a numpy array, one row per point."""
    import numpy as np

    raw = path.read_bytes()
    at = raw.index(b"end_header\n") + len(b"end_header\n")
    header = raw[:at].decode()
    n = int(header.split("element vertex ")[1].split()[0])
    props = header.count("property ")
    return np.frombuffer(raw[at:at + 4 * n * props], dtype="<f4").reshape(n, props)[:, :7]


def check_usd(out, manifest):
    import numpy as np
    from pxr import Usd, UsdGeom, UsdValidation

    path = usd_file(out)
    if path.suffix == ".usdc":
        check("usd file is binary (crate format)", path.read_bytes()[:8] == b"PXR-USDC", path.name)
    stage = Usd.Stage.Open(str(path))
    n = len(manifest["frames"])
    first, last = frame_range(manifest)
    fps = manifest["fps"]
    check(f"usd time codes {first}..{last} (the shot's frames)",
          (stage.GetStartTimeCode(), stage.GetEndTimeCode()) == (first, last),
          (stage.GetStartTimeCode(), stage.GetEndTimeCode()))
    check("usd timeCodesPerSecond and framesPerSecond = fps",
          abs(stage.GetTimeCodesPerSecond() - fps) < 1e-9 and abs(stage.GetFramesPerSecond() - fps) < 1e-9,
          (stage.GetTimeCodesPerSecond(), stage.GetFramesPerSecond()))
    check("usd upAxis Y, metersPerUnit 1",
          UsdGeom.GetStageUpAxis(stage) == "Y" and UsdGeom.GetStageMetersPerUnit(stage) == 1.0)
    pts = UsdGeom.Points(stage.GetPrimAtPath("/Morph/particles"))
    count = manifest["particles"]
    for t in (first, last):
        check(f"usd particles at frame {t}: points, velocities",
              len(pts.GetPointsAttr().Get(t)) == count and len(pts.GetVelocitiesAttr().Get(t)) == count,
              count)
    # The values are the PLY frames' own float32 numbers, bit for bit.
    for t, frame in ((first, manifest["frames"][0]), (last, manifest["frames"][-1])):
        ply = ply_frame(out / frame["points"])
        usd = np.hstack([np.array(pts.GetPointsAttr().Get(t), dtype="<f4"),
                         np.array(pts.GetVelocitiesAttr().Get(t), dtype="<f4"),
                         np.array(UsdGeom.PrimvarsAPI(pts).GetPrimvar("J").Get(t), dtype="<f4")[:, None]])
        check(f"usd particles at frame {t}: points, velocities, J bit for bit the PLY frame's float32",
              usd.shape == ply.shape and usd.tobytes() == ply.tobytes(), (usd.shape, ply.shape))
    check("usd ids", list(pts.GetIdsAttr().Get()) == list(range(count)))
    j = UsdGeom.PrimvarsAPI(pts).GetPrimvar("J")
    check("usd primvars:J per point", j.GetInterpolation() == "vertex" and len(j.Get(last)) == count)
    rest = UsdGeom.PrimvarsAPI(pts).GetPrimvar("rest")
    check("usd particles: primvars:rest (vertex) = the first frame's points",
          rest.GetInterpolation() == "vertex" and list(rest.Get()) == list(pts.GetPointsAttr().Get(first)))
    has_carried, has_rebuilt = surfaces_of(manifest)
    if has_carried:
        check_usd_carried(out, manifest, stage, last)
    else:
        print("     (no carried surface in this output: its checks skipped)")
    if has_rebuilt:
        rebuilt = UsdGeom.Mesh(stage.GetPrimAtPath("/Morph/rebuilt"))
        check("usd rebuilt mesh: points on every frame",
              all(len(rebuilt.GetPointsAttr().Get(t)) > 0 for t in range(first, last + 1)))
    else:
        print("     (no rebuilt surface in this output: its checks skipped)")
    if manifest["settings"]["outputs"].get("volume"):
        check_usd_volume(out, manifest, stage)
    else:
        print("     (no volumes in this output (--volume): their checks skipped)")
    validators = UsdValidation.ValidationRegistry().GetOrLoadAllValidators()
    errors = UsdValidation.ValidationContext(validators).Validate(stage)
    check(f"usd validators ({len(validators)}, what usdchecker runs): no errors", len(errors) == 0,
          [e.GetMessage() for e in errors][:5])


def surfaces_of(manifest):
    """Whether the output has a carried and a rebuilt surface (--surface decides)."""
    first = manifest["frames"][0]
    return "carried_mesh" in first, "mesh" in first


def volume_file(frame):
    """A frame's volume file (--volume): named as its points."""
    return frame["points"].replace("frames/", "volumes/").replace(".ply", ".vdb")


def check_usd_volume(out, manifest, stage):
    from pxr import UsdVol

    volume = UsdVol.Volume(stage.GetPrimAtPath("/Morph/volume"))
    fields = volume.GetFieldPaths() if volume else {}
    check("usd volume: a Volume prim with a density field", list(fields) == ["density"], dict(fields))
    asset = UsdVol.OpenVDBAsset(stage.GetPrimAtPath(fields.get("density", "/Morph/volume/density")))
    first, last = frame_range(manifest)
    for t, frame in ((first, manifest["frames"][0]), (last, manifest["frames"][-1])):
        path = asset.GetFilePathAttr().Get(t)
        check(f"usd volume at frame {t}: the density grid's file is the frame's",
              path is not None and Path(path.resolvedPath) == (out / volume_file(frame)).resolve()
              and asset.GetFieldNameAttr().Get() == "density", path)


def check_usd_carried(out, manifest, stage, last):
    from pxr import UsdGeom

    carried = UsdGeom.Mesh(stage.GetPrimAtPath("/Morph/carried"))
    sv, svt, sf = obj_counts(out / manifest["frames"][0]["carried_mesh"])
    check("usd carried mesh: source's vertex and face counts",
          len(carried.GetPointsAttr().Get(last)) == sv and len(carried.GetFaceVertexCountsAttr().Get()) == sf,
          (sv, sf))
    st = UsdGeom.PrimvarsAPI(carried).GetPrimvar("st")
    check("usd carried mesh: st primvar (faceVarying) with the source's UVs",
          st.GetInterpolation() == "faceVarying" and len(st.Get()) == svt, svt)
    rest = UsdGeom.PrimvarsAPI(carried).GetPrimvar("rest")
    first = frame_range(manifest)[0]
    check("usd carried mesh: primvars:rest (vertex) = the first frame's points",
          rest.GetInterpolation() == "vertex" and list(rest.Get()) == list(carried.GetPointsAttr().Get(first)))
    check("usd carried mesh: velocities", len(carried.GetVelocitiesAttr().Get(frame_range(manifest)[0] + 1)) == sv)


def check_blender(out, manifest):
    import bpy

    first, last = frame_range(manifest)
    fps = manifest["fps"]
    bpy.ops.wm.read_factory_settings(use_empty=True)
    bpy.ops.wm.usd_import(filepath=str(usd_file(out)), set_frame_range=True)
    scene = bpy.context.scene
    check(f"blender frame range from the USD: {first}..{last} (frame_start = the start frame)",
          (scene.frame_start, scene.frame_end) == (first, last),
          (scene.frame_start, scene.frame_end))
    check("blender fps from the USD", abs(scene.render.fps / scene.render.fps_base - fps) < 1e-6,
          scene.render.fps / scene.render.fps_base)
    objects = {o.name: o for o in scene.objects}
    print("     blender objects:", sorted(objects))
    scene.frame_set(last)
    depsgraph = bpy.context.evaluated_depsgraph_get()
    particles = objects.get("particles")
    check("blender particles object", particles is not None)
    if particles is not None:
        data = particles.evaluated_get(depsgraph).data
        check("blender point count", len(data.vertices if hasattr(data, "vertices") else data.points) == manifest["particles"],
              manifest["particles"])
        names = [a.name for a in data.attributes]
        check("blender velocity attribute on the points", "velocity" in names, names)
        check("blender rest attribute on the points", "rest" in names, names)
    has_carried, has_rebuilt = surfaces_of(manifest)
    carried = objects.get("carried")
    sv = None
    if has_carried:
        sv, svt, sf = obj_counts(out / manifest["frames"][0]["carried_mesh"])
        check("blender carried mesh", carried is not None)
    if carried is not None and has_carried:
        mesh = carried.evaluated_get(depsgraph).data
        check("blender carried mesh: the source's vertex count", len(mesh.vertices) == sv, (len(mesh.vertices), sv))
        check("blender carried mesh: a UV layer", len(mesh.uv_layers) >= 1, [u.name for u in mesh.uv_layers])
        check("blender carried mesh: rest attribute", "rest" in [a.name for a in mesh.attributes],
              [a.name for a in mesh.attributes])

    if manifest["settings"]["outputs"].get("volume"):
        check("blender volume object from the USD", objects.get("volume") is not None
              and objects["volume"].type == "VOLUME", sorted(objects))
        check_blender_volume(out, manifest)

    # The final mass grid as a volume (OpenVDB), within the grid's extent.
    bpy.ops.wm.read_factory_settings(use_empty=True)
    bpy.ops.object.volume_import(filepath=str(out / "final_mass.vdb"))
    volume = bpy.context.selected_objects[0]
    loaded = volume.data.grids.load()
    check("blender final_mass.vdb: a volume with its grid 'mass'",
          loaded and [g.name for g in volume.data.grids] == ["mass"], [g.name for g in volume.data.grids])
    header = mgrid_header(out / "final_mass.mgrid")
    lo = header["origin"]
    # Blender bounds a volume by whole leaves (8 voxels a side).
    hi = [o + 8 * -(-d // 8) * header["dx"] for o, d in zip(lo, header["dims"])]
    corners = [volume.matrix_world @ __import__("mathutils").Vector(c) for c in volume.bound_box]
    inside = all(lo[i] - header["dx"] <= min(c[i] for c in corners) and max(c[i] for c in corners) <= hi[i] + header["dx"]
                 for i in range(3))
    check("blender final_mass.vdb: bounds within the grid's extent (in whole leaves)", inside,
          ([min(c[i] for c in corners) for i in range(3)], [max(c[i] for c in corners) for i in range(3)]))

    # The loose files: a carried OBJ keeps its UVs; a rebuilt OBJ and a PLY frame import.
    bpy.ops.wm.read_factory_settings(use_empty=True)
    last = manifest["frames"][-1]
    if has_carried:
        bpy.ops.wm.obj_import(filepath=str(out / last["carried_mesh"]))
        obj = bpy.context.selected_objects[0]
        check("blender carried OBJ: vertex count and UVs",
              len(obj.data.vertices) == sv and len(obj.data.uv_layers) == 1,
              (len(obj.data.vertices), len(obj.data.uv_layers)))
    rebuilt_obj = None
    if has_rebuilt:
        bpy.ops.wm.obj_import(filepath=str(out / last["mesh"]))
        obj = bpy.context.selected_objects[0]
        check("blender rebuilt OBJ imports", len(obj.data.vertices) > 0, len(obj.data.vertices))
        rebuilt_obj = obj
    bpy.ops.wm.ply_import(filepath=str(out / last["points"]), forward_axis="NEGATIVE_Z", up_axis="Y")
    obj = bpy.context.selected_objects[0]
    names = [a.name for a in obj.data.attributes]
    check("blender PLY frame: points and vx vy vz J attributes",
          len(obj.data.vertices) == manifest["particles"] and all(k in names for k in ("vx", "vy", "vz", "J")),
          names)
    header = open(out / last["points"], "rb").read(400).split(b"end_header")[0].decode()
    # Blender 4.5's PLY importer drops a property named `id` (Houdini reads it); the file has it.
    check("PLY frame: an int id property", "property int id" in header)

    def centre(o):
        pts = [o.matrix_world @ v.co for v in o.data.vertices]
        return [sum(p[i] for p in pts) / len(pts) for i in range(3)]

    if rebuilt_obj is not None:
        a, b = centre(obj), centre(rebuilt_obj)
        size = max(rebuilt_obj.dimensions)
        check("blender PLY (forward -Z, up Y, as the README says) lines up with the OBJ surface",
              max(abs(a[i] - b[i]) for i in range(3)) < 0.05 * size, (a, b))


def check_blender_volume(out, manifest):
    """The last frame's volume imports as a volume around the frame's rebuilt surface."""
    import bpy
    from mathutils import Vector

    last = manifest["frames"][-1]
    bpy.ops.wm.read_factory_settings(use_empty=True)
    bpy.ops.object.volume_import(filepath=str(out / volume_file(last)))
    volume = bpy.context.selected_objects[0]
    check("blender frame volume: its grid 'density'",
          volume.data.grids.load() and [g.name for g in volume.data.grids] == ["density"],
          [g.name for g in volume.data.grids])
    corners = [volume.matrix_world @ Vector(c) for c in volume.bound_box]
    lo = [min(c[i] for c in corners) for i in range(3)]
    hi = [max(c[i] for c in corners) for i in range(3)]
    if "mesh" in last:
        bpy.ops.wm.obj_import(filepath=str(out / last["mesh"]))
        mesh = bpy.context.selected_objects[0]
        pts = [mesh.matrix_world @ v.co for v in mesh.data.vertices]
        mlo = [min(p[i] for p in pts) for i in range(3)]
        mhi = [max(p[i] for p in pts) for i in range(3)]
        # Blender bounds a volume by whole leaves (8 voxels): around the surface, not far off.
        size = max(mhi[i] - mlo[i] for i in range(3))
        check("blender frame volume: bounds around the frame's rebuilt surface",
              all(lo[i] <= mlo[i] and mhi[i] <= hi[i] and hi[i] - lo[i] < 2 * size for i in range(3)),
              (lo, hi, mlo, mhi))


def main():
    if len(sys.argv) != 2:
        sys.exit(__doc__)
    out = Path(sys.argv[1])
    manifest = json.load(open(out / "manifest.json"))
    check_usd(out, manifest)
    check_blender(out, manifest)
    usd = usd_file(out).stat().st_size
    loose = sum(p.stat().st_size for d in ("frames", "meshes", "carried") if (out / d).is_dir()
                for p in (out / d).glob("*"))
    print(f"     sizes: {usd_file(out).name} {usd / 1e6:.1f} MB, frames/ meshes/ carried/ {loose / 1e6:.1f} MB")
    print(f"clients: {len(passed)} passed, {len(failures)} failed")
    if failures:
        print(f"first failure: {failures[0]}")
        sys.exit(1)


if __name__ == "__main__":
    main()

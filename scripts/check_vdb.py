"""Reads a morph's final_mass.vdb with OpenVDB's own library (Debian's python3-openvdb) and
checks it against final_mass.mgrid: one float grid `mass`, the same sum (relative 1e-6; the
VDB holds f32), voxel (0, 0, 0) at the grid's origin. With --volume, the first and the last
frame's volumes/frame_NNNN.vdb: a float grid `density` from 0 to about 1 whose integral is the
frame's rebuilt surface's volume (5%). Usage: python3 scripts/check_vdb.py OUT
"""
import array
import json
import struct
import sys
from pathlib import Path

import pyopenvdb as vdb

out = Path(sys.argv[1])
failed = 0


def check(what, ok, detail=""):
    global failed
    print(("ok   " if ok else "FAIL ") + what + (f": {detail}" if detail != "" else ""))
    failed += not ok


raw = (out / "final_mass.mgrid").read_bytes()
n = struct.unpack("<I", raw[8:12])[0]
header = json.loads(raw[12:12 + n])
count = header["dims"][0] * header["dims"][1] * header["dims"][2]
values = array.array("d")
values.frombytes(raw[12 + n:12 + n + 8 * count])
grids = vdb.readAllGridMetadata(str(out / "final_mass.vdb"))
check("vdb: one float grid named mass", [g.name for g in grids] == ["mass"], [g.name for g in grids])
grid = vdb.read(str(out / "final_mass.vdb"), "mass")
check("vdb: a FloatGrid", isinstance(grid, vdb.FloatGrid), type(grid).__name__)
total = sum(v.value for v in grid.citerOnValues())
expected = sum(values)
check("vdb: voxel sum = the .mgrid's (relative 1e-6)", abs(total - expected) <= 1e-6 * abs(expected),
      (total, expected))
check("vdb: active voxels = the .mgrid's nonzero nodes", grid.activeVoxelCount() == sum(v != 0 for v in values),
      grid.activeVoxelCount())
origin = grid.transform.indexToWorld((0, 0, 0))
check("vdb: voxel (0, 0, 0) at the grid's origin",
      all(abs(a - b) <= 1e-9 * max(1.0, abs(b)) for a, b in zip(origin, header["origin"])), origin)
# The per-frame volumes (--volume): a density grid whose integral is the frame's volume.
manifest = json.load(open(out / "manifest.json"))
frames = manifest["frames"]
if manifest["settings"]["outputs"].get("volume"):
    for frame in (frames[0], frames[-1]):
        name = frame["points"].replace("frames/", "volumes/").replace(".ply", ".vdb")
        grid = vdb.read(str(out / name), "density")
        dx = grid.transform.voxelSize()[0]
        values = [v.value for v in grid.citerOnValues()]
        volume = sum(values) * dx ** 3
        check(f"{name}: a float grid 'density', fill from 0 to about 1", isinstance(grid, vdb.FloatGrid)
              and min(values) >= 0 and 0.9 < max(values) < 2, (min(values), max(values)))
        if "surface_volume" in frame:
            expected = frame["surface_volume"]
            check(f"{name}: integral = the rebuilt surface's volume (5%)",
                  abs(volume - expected) <= 0.05 * expected, (volume, expected))
else:
    print("     (no volumes in this output (--volume): their checks skipped)")
print(f"vdb: {failed} failed")
sys.exit(1 if failed else 0)

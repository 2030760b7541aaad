"""Opens a morph's USD file with an older Pixar USD (scripts/client-check.sh runs it with
usd-core 24.3, the oldest on PyPI, of the generation Houdini 20 and Maya 2025 ship) and reads
every time sample of every attribute. Usage: python scripts/check_usd_compat.py OUT
"""
import json
import sys
from pathlib import Path

from pxr import Usd, UsdGeom

out = Path(sys.argv[1])
manifest = json.loads((out / "manifest.json").read_text())
path = out / "morph.usdc"
if not path.exists():
    path = out / "morph.usda"
stage = Usd.Stage.Open(str(path))
version = ".".join(map(str, Usd.GetVersion()))
prims = [str(p.GetPath()) for p in stage.Traverse()]
samples = 0
for prim in stage.Traverse():
    for attribute in prim.GetAttributes():
        for t in attribute.GetTimeSamples():
            attribute.Get(t)
            samples += 1
points = UsdGeom.Points(stage.GetPrimAtPath("/Morph/particles"))
last = stage.GetEndTimeCode()
ok = "/Morph/particles" in prims and len(points.GetPointsAttr().Get(last)) == manifest["particles"]
print(f"{'ok  ' if ok else 'FAIL'} usd-core {version} opens {path.name}: {len(prims)} prims, "
      f"{samples} time samples read, {manifest['particles']} points on the last frame")
sys.exit(0 if ok else 1)

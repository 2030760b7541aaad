#!/usr/bin/env python3
"""Builds the Blender extension (blender/morph_blender) around a morph wheel:

    python3 scripts/build-blender-extension.py WHEEL OUT.zip

The zip holds blender_manifest.toml at its root, the add-on's __init__.py and the wheel in
wheels/ (the manifest names it); Blender 4.2 and later install it with Edit > Preferences >
Get Extensions > Install from Disk, or `bpy.ops.extensions.package_install_files`.
"""
import sys
import zipfile
from pathlib import Path

wheel, out = Path(sys.argv[1]), Path(sys.argv[2])
source = Path(__file__).resolve().parent.parent / "blender" / "morph_blender"
manifest = (source / "blender_manifest.toml").read_text()
if "./wheels/WHEEL" not in manifest:
    sys.exit("build-blender-extension: the manifest's wheels line is not the placeholder")
manifest = manifest.replace("./wheels/WHEEL", f"./wheels/{wheel.name}")
out.parent.mkdir(parents=True, exist_ok=True)
tmp = out.with_name(out.name + ".tmp")
with zipfile.ZipFile(tmp, "w", zipfile.ZIP_DEFLATED) as z:
    z.writestr("blender_manifest.toml", manifest)
    z.write(source / "__init__.py", "__init__.py")
    z.write(wheel, f"wheels/{wheel.name}")
tmp.replace(out)
print(f"build-blender-extension: {out} ({out.stat().st_size / 1e6:.1f} MB)")

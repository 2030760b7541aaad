#!/usr/bin/env python3
"""Writes shapes that were never used to tune morph (issue 29's held-out check), as closed OBJ
meshes of star-shaped bodies: r(theta, phi) along each direction, on a UV sphere grid.

    python3 scripts/heldout_shapes.py OUTDIR

- `horned.obj`: a ball with six horns (thin features a particle or two wide at resolution 32);
- `tall.obj`: a body three times taller than wide with a head on a narrow neck (a tall target
  leaves the source fewer particles at a fixed resolution);
- `lumpy.obj`: a ball with many shallow bumps (detail at the scale of a few spacings).

Plain Python, no packages: deterministic, the same files every time. An existing file of
the same name is left alone when it is the same, and refused when it differs.
"""
import math
import os
import sys


def star(path, shape, rings=96, segments=192, stretch=(1.0, 1.0, 1.0)):
    verts = [(0.0, shape(0.0, 0.0) * stretch[1], 0.0)]
    for i in range(1, rings):
        t = math.pi * i / rings
        for j in range(segments):
            p = 2 * math.pi * j / segments
            r = shape(t, p)
            verts.append((r * math.sin(t) * math.cos(p) * stretch[0],
                          r * math.cos(t) * stretch[1],
                          r * math.sin(t) * math.sin(p) * stretch[2]))
    verts.append((0.0, -shape(math.pi, 0.0) * stretch[1], 0.0))
    faces = []
    ring = lambda i, j: 1 + (i - 1) * segments + (j % segments)
    for j in range(segments):
        faces.append((0, ring(1, j + 1), ring(1, j)))
    for i in range(1, rings - 1):
        for j in range(segments):
            a, b, c, d = ring(i, j), ring(i, j + 1), ring(i + 1, j), ring(i + 1, j + 1)
            faces.append((a, b, d))
            faces.append((a, d, c))
    last = len(verts) - 1
    for j in range(segments):
        faces.append((last, ring(rings - 1, j), ring(rings - 1, j + 1)))
    text = "# morph held-out shape (scripts/heldout_shapes.py)\n"
    text += "".join("v %.6f %.6f %.6f\n" % v for v in verts)
    text += "".join("f %d %d %d\n" % (a + 1, b + 1, c + 1) for a, b, c in faces)
    if os.path.exists(path):
        # Never replace a file this script did not write the same way.
        with open(path) as f:
            if f.read() != text:
                sys.exit(f"heldout_shapes: error: {path} exists and differs; choose another folder")
        return
    tmp = path + ".part"
    with open(tmp, "w") as f:
        f.write(text)
    os.replace(tmp, path)


def direction(t, p):
    return (math.sin(t) * math.cos(p), math.cos(t), math.sin(t) * math.sin(p))


def horned(t, p):
    d = direction(t, p)
    r = 1.0
    for axis in [(1, 0, 0), (-1, 0, 0), (0, 1, 0), (0, -1, 0), (0, 0, 1), (0, 0, -1)]:
        c = sum(a * b for a, b in zip(d, axis))
        angle = math.acos(max(-1.0, min(1.0, c)))
        r += 0.8 * math.exp(-(angle / 0.12) ** 2)
    return r


def tall(t, p):
    # Height along y: a body, a narrow neck at y = 0.55, a head above it.
    y = math.cos(t)
    neck = 1.0 - 0.55 * math.exp(-((y - 0.55) / 0.12) ** 2)
    head = 1.0 + 0.25 * math.exp(-((y - 0.8) / 0.15) ** 2)
    return neck * head


def lumpy(t, p):
    return 1.0 + 0.08 * math.sin(5 * t) * math.sin(6 * p) + 0.05 * math.sin(9 * t + 1.0) * math.cos(7 * p)


def main():
    out = sys.argv[1] if len(sys.argv) > 1 else sys.exit(__doc__)
    os.makedirs(out, exist_ok=True)
    star(os.path.join(out, "horned.obj"), horned, rings=128, segments=256)
    star(os.path.join(out, "tall.obj"), tall, stretch=(0.35, 1.0, 0.35))
    star(os.path.join(out, "lumpy.obj"), lumpy)
    print("wrote horned.obj, tall.obj, lumpy.obj into", out)


if __name__ == "__main__":
    main()

"""morph: turn one 3D shape into another with a differentiable MPM simulation.

    import morph
    result = morph.run("sphere.obj", "bunny.obj", preset="draft")      # frames in memory
    result = morph.run("sphere.obj", ["a.obj", "b.obj"], at=[30, 73], out="shot")  # a folder

Meshes are file paths, or ``(vertices, triangles)`` arrays (n x 3 floats, m x 3 integers).
Settings are the scene file's keys (docs/scenes.md), as keyword arguments: ``preset``,
``resolution``, ``frames``, ``fps``, ``material={"youngs_modulus": 2e5}``, ...

``on_event(event)`` receives the events ``morph --json`` prints (dicts), each with
``progress``, the fraction of the run done (0 to 1, as ``--progress openjd``); ``on_frame(frame)``
each frame as it is made (a :class:`Frame`). Either may return ``False`` to cancel: the run stops at its
next evaluation and raises :class:`Cancelled`, as Ctrl-C does. Errors raise a
:class:`MorphError` subclass whose message is the command line's. The simulation runs without
the GIL.
"""

import json
import os
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from . import _morph
from ._morph import (
    Cancelled,
    MeshError,
    MorphError,
    OutputError,
    SettingsError,
    SimulationError,
    __version__,
)

__all__ = [
    "run", "inspect", "compare", "Result", "Frame", "MorphError", "SettingsError", "MeshError",
    "SimulationError", "OutputError", "Cancelled", "__version__",
]


@dataclass
class Frame:
    """One frame, in the source mesh's units: ``positions`` and ``velocities`` (n x 3),
    ``J`` (n; volume ratio), ``ids`` (n; the particles' numbers, as the PLY frames' ``id``)."""
    index: int
    time: float
    positions: np.ndarray
    velocities: np.ndarray
    J: np.ndarray
    ids: np.ndarray


@dataclass
class Result:
    """What a run gives back: the judge's verdict (``quality``: fill, reach, ...), the losses,
    and either the frames (in memory) or the output folder with its manifest."""
    quality: dict
    initial_loss: float
    final_loss: float
    seconds: float
    fps: float | None = None
    frames: list[Frame] = field(default_factory=list)
    out: Path | None = None
    manifest: dict | None = None
    summary: dict | None = None


def _mesh(arg, name):
    if isinstance(arg, (str, os.PathLike)):
        return os.fspath(arg)
    try:
        vertices, triangles = arg
    except (TypeError, ValueError):
        raise MeshError(f"'{name}': a mesh is a file path or (vertices, triangles) arrays") from None
    vertices = np.ascontiguousarray(vertices, dtype=np.float64)
    triangles = np.ascontiguousarray(triangles, dtype=np.int64)
    if vertices.ndim != 2 or triangles.ndim != 2:
        raise MeshError(f"'{name}': vertices and triangles must be 2-d arrays (n x 3, m x 3)")
    return (name, vertices, triangles)


def _frame(d):
    n = len(d["J"])
    return Frame(d["index"], d["time"], d["positions"], d["velocities"], d["J"],
                 np.arange(n, dtype=np.int32))


def run(source, targets, at=None, out=None, *, overwrite=False, resume=False, on_event=None,
        on_frame=None, **settings):
    """Morphs ``source`` into ``targets`` (one mesh or a list, reached in turn, each at its
    frame in ``at``). Without ``out`` the frames come back as numpy arrays; with ``out`` the
    folder the command line writes (``overwrite``, ``resume`` as there)."""
    if isinstance(targets, (str, os.PathLike)) or (
            isinstance(targets, tuple) and len(targets) == 2 and not isinstance(targets[0], (str, os.PathLike))):
        targets = [targets]
    if at is not None:
        settings["at"] = [at] if isinstance(at, int) else list(at)
    try:
        settings_json = json.dumps(settings)
    except TypeError as e:
        raise SettingsError(f"settings: {e}") from None
    events = None if on_event is None else (lambda text: on_event(json.loads(text)))
    frames = None if on_frame is None else (lambda d: on_frame(_frame(d)))
    source = _mesh(source, "<source>")
    targets = [_mesh(t, f"<target {i + 1}>") for i, t in enumerate(targets)]
    if out is not None:
        summary = json.loads(_morph.run(source, targets, settings_json, out=os.fspath(out),
                                        overwrite=overwrite, resume=resume, on_event=events,
                                        on_frame=frames))
        out = Path(summary["output"])
        manifest = json.loads((out / "manifest.json").read_text())
        return Result(quality=summary.get("quality") or {}, initial_loss=summary["initial_loss"],
                      final_loss=summary["final_loss"], seconds=summary["seconds"],
                      fps=manifest.get("fps"), out=out, manifest=manifest, summary=summary)
    r = _morph.run(source, targets, settings_json, on_event=events, on_frame=frames)
    return Result(quality=json.loads(r["quality"]), initial_loss=r["initial_loss"],
                  final_loss=r["final_loss"], seconds=r["seconds"], fps=r["fps"],
                  frames=[_frame(d) for d in r["frames"]])


def inspect(mesh, resolution=32):
    """What morph makes of a mesh (``morph inspect``): its size, volume, repairs, particles."""
    return json.loads(_morph.inspect(os.fspath(mesh), resolution))


def compare(a, b, rtol=1e-5, atol=1e-8):
    """Two nodal mass grids (``final_mass.mgrid``) within tolerance or not (``morph compare``)."""
    return json.loads(_morph.compare(os.fspath(a), os.fspath(b), rtol, atol))

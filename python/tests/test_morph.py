"""The Python module against the command line: same frames bit for bit, cancels, errors.

Run by scripts/python-check.sh (what .ci/run calls) after it builds the wheel; MORPH_BIN names
the CLI built from the same tree (default: target/release/morph).
"""

import json
import os
import subprocess
import threading
from pathlib import Path

import numpy as np
import pytest

import morph

ROOT = Path(__file__).resolve().parents[2]
ASSETS = ROOT / "assets"
MORPH = Path(os.environ.get("MORPH_BIN", ROOT / "target" / "release" / "morph"))
# A small morph of the built-in assets, the same for the CLI and the module.
SMALL = {"preset": "draft", "resolution": 16, "segments": 2}
CLI_SMALL = ["--preset", "draft", "--resolution", "16", "--segments", "2"]


def ply(path):
    """A frame PLY: its float32 columns x y z vx vy vz J and its int32 ids."""
    raw = path.read_bytes()
    at = raw.index(b"end_header\n") + len(b"end_header\n")
    header = raw[:at].decode()
    n = int(header.split("element vertex ")[1].split()[0])
    row = np.dtype([("c", "<f4", 7), ("id", "<i4")])
    data = np.frombuffer(raw[at:at + n * row.itemsize], dtype=row)
    return data["c"], data["id"]


def read_obj(path):
    v, f = [], []
    for line in open(path):
        w = line.split()
        if w and w[0] == "v":
            v.append([float(x) for x in w[1:4]])
        elif w and w[0] == "f":
            f.append([int(c.split("/")[0]) - 1 for c in w[1:4]])
    return np.array(v), np.array(f)


@pytest.fixture(scope="module")
def cli_frames(tmp_path_factory):
    out = tmp_path_factory.mktemp("cli") / "out"
    subprocess.run([str(MORPH), str(ASSETS / "sphere.obj"), str(ASSETS / "cube.obj"), "-o", str(out),
                    "--surface", "none", "--usd", "none", "--quiet", *CLI_SMALL], check=True)
    manifest = json.loads((out / "manifest.json").read_text())
    return [ply(out / f["points"]) for f in manifest["frames"]]


def test_frames_in_memory_are_the_cli_frames_bit_for_bit(cli_frames):
    result = morph.run(ASSETS / "sphere.obj", ASSETS / "cube.obj", **SMALL)
    assert len(result.frames) == len(cli_frames)
    for frame, (columns, ids) in zip(result.frames, cli_frames):
        mine = np.hstack([frame.positions, frame.velocities, frame.J[:, None]]).astype("<f4")
        assert mine.tobytes() == np.ascontiguousarray(columns).tobytes(), frame.index
        assert np.array_equal(frame.ids, ids)
    assert 0.5 < result.quality["fill"] <= 1.0
    assert result.final_loss < result.initial_loss


def test_meshes_as_arrays_give_the_same_morph(cli_frames):
    source, target = read_obj(ASSETS / "sphere.obj"), read_obj(ASSETS / "cube.obj")
    result = morph.run(source, target, **SMALL)
    last = np.hstack([result.frames[-1].positions, result.frames[-1].velocities,
                      result.frames[-1].J[:, None]]).astype("<f4")
    assert last.tobytes() == np.ascontiguousarray(cli_frames[-1][0]).tobytes()


def test_events_are_the_json_events_and_returning_false_cancels():
    seen = []

    def on_event(event):
        seen.append(event["event"])
        return event["event"] != "iteration"

    with pytest.raises(morph.Cancelled):
        morph.run(ASSETS / "sphere.obj", ASSETS / "cube.obj", on_event=on_event, **SMALL)
    assert seen[0] == "setup" and seen.count("iteration") == 1 and "done" not in seen


def test_on_frame_sees_each_frame_and_returning_false_cancels():
    indices = []

    def on_frame(frame):
        indices.append(frame.index)
        assert frame.positions.shape == (len(frame.J), 3)
        return frame.index < 2

    with pytest.raises(morph.Cancelled):
        morph.run(ASSETS / "sphere.obj", ASSETS / "cube.obj", on_frame=on_frame, **SMALL)
    assert indices[:3] == [0, 1, 2] and len(indices) < 13


def test_an_exception_in_a_callback_stops_the_run_and_is_raised():
    def on_event(event):
        raise KeyError("from the callback")

    with pytest.raises(KeyError, match="from the callback"):
        morph.run(ASSETS / "sphere.obj", ASSETS / "cube.obj", on_event=on_event, **SMALL)


def test_bad_settings_raise_the_cli_message(tmp_path):
    # An option the command line and the settings check alike.
    cli = subprocess.run([str(MORPH), str(ASSETS / "sphere.obj"), str(ASSETS / "cube.obj"), "-o",
                          str(tmp_path / "out"), "--resolution", "1"], capture_output=True, text=True)
    assert cli.returncode == 2
    with pytest.raises(morph.SettingsError) as raised:
        morph.run(ASSETS / "sphere.obj", ASSETS / "cube.obj", resolution=1)
    assert isinstance(raised.value, morph.MorphError)
    assert str(raised.value) == cli.stderr.strip().removeprefix("morph: error: ")
    # A scene key: the message of `morph --scene` on the same keys, the file named "settings".
    scene = tmp_path / "shot.json"
    scene.write_text(json.dumps({"material": {"youngs_modulus": -5}}))
    cli = subprocess.run([str(MORPH), str(ASSETS / "sphere.obj"), str(ASSETS / "cube.obj"), "-o",
                          str(tmp_path / "out"), "--scene", str(scene)], capture_output=True, text=True)
    assert cli.returncode == 2
    with pytest.raises(morph.SettingsError) as raised:
        morph.run(ASSETS / "sphere.obj", ASSETS / "cube.obj", material={"youngs_modulus": -5})
    expected = cli.stderr.strip().removeprefix("morph: error: ").replace(f"scene file '{scene}':", "settings:")
    assert str(raised.value) == expected


def test_a_setting_has_the_same_name_in_python_the_scene_file_and_set(tmp_path):
    # `iterations` (the command line's name) and `optimizer={"iterations": ...}` (the scene
    # file's) are one setting: both are read, and a bad value says what `--set` says.
    cli = subprocess.run([str(MORPH), str(ASSETS / "sphere.obj"), str(ASSETS / "cube.obj"), "-o",
                          str(tmp_path / "out"), "--set", "iterations=0"], capture_output=True, text=True)
    assert cli.returncode == 2
    for settings in ({"iterations": 0}, {"optimizer": {"iterations": 0}}):
        with pytest.raises(morph.SettingsError) as raised:
            morph.run(ASSETS / "sphere.obj", ASSETS / "cube.obj", **settings)
        assert str(raised.value) == cli.stderr.strip().removeprefix("morph: error: ")


def test_a_bad_mesh_raises_the_cli_message(tmp_path):
    bad = tmp_path / "bad.obj"
    bad.write_text("v 0 0 0\nv 1 0 0\nf 1 2 3\n")
    cli = subprocess.run([str(MORPH), str(bad), str(ASSETS / "cube.obj"), "-o", str(tmp_path / "o")],
                         capture_output=True, text=True)
    with pytest.raises(morph.MeshError) as raised:
        morph.run(bad, ASSETS / "cube.obj", **SMALL)
    assert str(raised.value) == cli.stderr.strip().removeprefix("morph: error: ")
    with pytest.raises(morph.MeshError):
        morph.run(([[0, 0, 0], [1, 0, 0]], [[0, 1, 5]]), ASSETS / "cube.obj")
    with pytest.raises(morph.SettingsError, match="unknown key `bogus`"):
        morph.run(ASSETS / "sphere.obj", ASSETS / "cube.obj", bogus=1)


def test_a_run_into_a_folder_is_the_cli_folder(tmp_path):
    events, frames = [], []
    result = morph.run(ASSETS / "sphere.obj", ASSETS / "cube.obj", out=tmp_path / "out",
                       on_event=events.append, on_frame=lambda f: frames.append(f.index),
                       surfaces="none", usd="none", **SMALL)
    assert result.out == tmp_path / "out" and (result.out / "final_mass.mgrid").is_file()
    assert len(result.manifest["frames"]) == 13 and events[-1]["event"] == "done"
    progress = [e["progress"] for e in events]
    assert progress == sorted(progress) and progress[0] == 0 and progress[-1] == 1
    assert frames == list(range(13))
    cli = tmp_path / "cli"
    subprocess.run([str(MORPH), str(ASSETS / "sphere.obj"), str(ASSETS / "cube.obj"), "-o", str(cli),
                    "--surface", "none", "--usd", "none", "--quiet", *CLI_SMALL], check=True)
    same = morph.compare(result.out / "final_mass.mgrid", cli / "final_mass.mgrid", rtol=0, atol=0)
    assert same["within_tolerance"] and same["max_abs_diff"] == 0
    # A second run on the same folder is refused, as on the command line.
    with pytest.raises(morph.MorphError, match="already exists; pass --overwrite"):
        morph.run(ASSETS / "sphere.obj", ASSETS / "cube.obj", out=tmp_path / "out", **SMALL)


def test_a_run_into_a_folder_cancelled_from_on_frame_keeps_its_checkpoint(tmp_path):
    with pytest.raises(morph.Cancelled):
        morph.run(ASSETS / "sphere.obj", ASSETS / "cube.obj", out=tmp_path / "out",
                  on_frame=lambda f: f.index < 3, **SMALL)
    # As after Ctrl-C: nothing in place, the completed segment kept for resume=True.
    assert not (tmp_path / "out").exists() and (tmp_path / "out.partial").is_dir()
    result = morph.run(ASSETS / "sphere.obj", ASSETS / "cube.obj", out=tmp_path / "out",
                       resume=True, **SMALL)
    assert result.summary["resumed_from"]


def test_ctrl_c_stops_a_run():
    import _thread
    import signal

    def on_event(event):
        if event["event"] == "iteration":
            _thread.interrupt_main()  # what Ctrl-C does: a KeyboardInterrupt in the main thread

    # Python's own Ctrl-C handler, as in a terminal (a job started in the background, as CI
    # may run this, inherits SIGINT ignored).
    previous = signal.signal(signal.SIGINT, signal.default_int_handler)
    try:
        with pytest.raises(KeyboardInterrupt):
            morph.run(ASSETS / "sphere.obj", ASSETS / "cube.obj", on_event=on_event, **SMALL)
    finally:
        signal.signal(signal.SIGINT, previous)


def test_the_gil_is_released_while_it_runs():
    ticks = []
    done = threading.Event()

    def tick():
        while not done.is_set():
            ticks.append(1)
            done.wait(0.01)

    thread = threading.Thread(target=tick)
    thread.start()
    try:
        result = morph.run(ASSETS / "sphere.obj", ASSETS / "cube.obj", **SMALL)
    finally:
        done.set()
        thread.join()
    assert len(ticks) > 0.5 * result.seconds / 0.01


def test_inspect():
    report = morph.inspect(ASSETS / "cube.obj")
    assert report["closed"] is True and report["genus"] == 0

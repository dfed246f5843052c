"""`render --from SHOT.npz` (issue 45): a shot recorded by --export-npz drawn again without
simulating it. The same frames, byte for byte, as the run that simulated it (same shader,
size, aa); another shader gives a direct render's frames with that shader; keyframed
colliders posed at each frame's time; a mesh cloth with its seams; and the refusals (exit
status 2, one line, nothing written). Tiny cloths, 64x64 images, a fifth of a second."""
from __future__ import annotations

import json
import os
from pathlib import Path

import numpy as np
import pytest

from conftest import cloth_dict, scene_dict
from pipeline.cli import main
from pipeline.run.shotfile import NPZ_FORMAT, read_shot

SMALL = scene_dict(  # no camera: framed over the whole shot
    cloth_dict(8, 8, thickness=0.0095, damping=0.2, density=150.0, ks=5000.0),
    spheres=[((0.5, 0.2, 0.5), 0.2, 0.3)], planes=[((0, 0, 0), (0, 1, 0), 0.5)])
#: a sphere keyframed across the view, fast, under a camera of the scene's own
MOVING = {
    **SMALL,
    "sphere": {"origin": [0.5, 0.2, 0.5], "radius": 0.15, "friction": 0.3,
               "keyframes": [{"time": 0.0}, {"time": 0.2, "translation": [0.6, 0.0, 0.0]}]},
    "camera": {"position": [0.6, 0.8, 2.4], "target": [0.6, 0.3, 0.4], "vfov": 45},
}
FAST = ["--size", "64x64", "--duration", "0.2", "--quiet"]


def run(capsys, *argv) -> tuple[int, str]:
    code = main([str(a) for a in argv])
    return code, capsys.readouterr().err


def write(folder: Path, name: str, data: dict) -> Path:
    path = folder / name
    path.write_text(json.dumps(data))
    return path


def pngs(folder: Path) -> dict[str, bytes]:
    return {p.name: p.read_bytes() for p in sorted(folder.glob("*.png"))}


def files(folder: Path) -> list[str]:
    return sorted(p.name for p in folder.iterdir())


@pytest.fixture
def shot(tmp_path, capsys):
    """SMALL simulated once: its phong frames (a folder) and its NPZ."""
    scene = write(tmp_path, "small.json", SMALL)
    code, err = run(capsys, scene, "--out", f"{tmp_path}/direct/", "--export-npz",
                    tmp_path / "shot.npz", *FAST)
    assert code == 0, err
    return scene, tmp_path / "shot.npz", tmp_path / "direct"


def test_the_npz_records_its_scene(shot):
    scene, npz, _ = shot
    data = np.load(npz, allow_pickle=False)  # plain arrays: no pickle needed
    assert int(data["npz_format"]) == NPZ_FORMAT == 2
    assert str(data["scene_name"]) == str(scene)
    assert str(data["scene_folder"]) == os.path.abspath(scene.parent)
    assert data["scene_json"].tobytes() == scene.read_bytes()
    assert data["scene_overrides"].tolist() == ["render.width=64", "render.height=64"]
    assert data["positions"].shape == (5, 64, 3)  # the older arrays as before
    assert data["sim_frames"].tolist() == [0, 4, 7, 11, 14]
    # no camera: what framed the shot (here every frame it holds)
    assert data["framing_frames"].tolist() == [0, 4, 7, 11, 14]
    assert data["framing_points"].dtype == np.float64 and data["framing_points"].shape[1] == 3
    s = read_shot(npz)
    assert s.scene.name == str(scene) and s.scene.data == scene.read_bytes()
    assert s.fps == 25 and s.sim_fps == 90 and s.points == 64


def test_from_gives_the_frames_of_the_simulating_run(shot, tmp_path, capsys):
    """Byte for byte, from the recorded scene and from the scene named; the scene file is
    not needed any more when the NPZ records it (its bytes are in the NPZ)."""
    scene, npz, direct = shot
    assert len(pngs(direct)) == 5
    code, err = run(capsys, "--from", npz, "--out", f"{tmp_path}/again/", "--quiet")
    assert code == 0, err
    assert pngs(tmp_path / "again") == pngs(direct)
    code, err = run(capsys, scene, "--from", npz, "--out", f"{tmp_path}/named/", "--size",
                    "64x64", "--quiet")
    assert code == 0, err
    assert pngs(tmp_path / "named") == pngs(direct)
    scene.unlink()
    code, err = run(capsys, "--from", npz, "--out", tmp_path / "moved.gif")
    assert code == 0, err
    assert "nothing simulated" in err and "simulate 0.00 s" in err


def test_another_shader_and_size_equal_a_direct_render_with_them(shot, tmp_path, capsys):
    scene, npz, direct = shot
    code, err = run(capsys, "--from", npz, "--out", f"{tmp_path}/toon/", "--shader", "toon")
    assert code == 0, err
    code, err = run(capsys, scene, "--out", f"{tmp_path}/toon_direct/", "--shader", "toon",
                    *FAST)
    assert code == 0, err
    toon = pngs(tmp_path / "toon")
    assert toon == pngs(tmp_path / "toon_direct")
    assert all(toon[name] != data for name, data in pngs(direct).items())
    # another size and one frame: the same as the run with those flags
    code, err = run(capsys, "--from", npz, "--out", tmp_path / "a.png", "--at", "0.08",
                    "--size", "48x32", "--aa", "2", "--quiet")
    assert code == 0, err
    code, err = run(capsys, scene, "--out", tmp_path / "b.png", "--at", "0.08", "--size",
                    "48x32", "--aa", "2", "--duration", "0.2", "--quiet")
    assert code == 0, err
    assert (tmp_path / "a.png").read_bytes() == (tmp_path / "b.png").read_bytes()


def test_fewer_frames_and_another_rate_within_the_npz(shot, tmp_path, capsys):
    """--frames 3 of the NPZ's 25 fps: its first three; --fps 5 over 0.2 s: frame 0."""
    _, npz, _ = shot
    code, err = run(capsys, "--from", npz, "--out", f"{tmp_path}/three/", "--frames", "3",
                    "--set", "camera.position=[0.5, 0.6, 2.2]", "--set",
                    "camera.target=[0.5, 0.4, 0]", "-q")
    assert code == 0, err
    assert len(pngs(tmp_path / "three")) == 3
    code, err = run(capsys, "--from", npz, "--out", tmp_path / "five.gif", "--fps", "5", "-q")
    assert code == 0, err


def test_a_keyframed_collider_is_drawn_at_each_frames_time(tmp_path, capsys):
    scene = write(tmp_path, "moving.json", MOVING)
    code, err = run(capsys, scene, "--out", f"{tmp_path}/direct/", "--export-npz",
                    tmp_path / "m.npz", *FAST)
    assert code == 0, err
    direct = pngs(tmp_path / "direct")
    code, err = run(capsys, "--from", tmp_path / "m.npz", "--out", f"{tmp_path}/again/", "-q")
    assert code == 0, err
    assert pngs(tmp_path / "again") == direct
    # the sphere moved 0.48 m by the last frame: drawn at t = 0 it would be elsewhere
    from PIL import Image

    from pipeline import load_scene
    from pipeline.run.frames import render_frame
    from pipeline.simulation import cloth_model

    s = load_scene(scene, ["render.width=64", "render.height=64"])
    last = np.load(tmp_path / "m.npz")["positions"][-1]
    still = render_frame(s, last, cloth_model(s), time=0.0)
    drawn = np.asarray(Image.open(tmp_path / "again" / "frame_00004.png"))
    assert (np.abs(still.astype(int) - drawn).max(axis=2) > 30).sum() > 20


def test_a_mesh_cloth_is_drawn_with_its_seams(tmp_path, capsys):
    from test_mesh_cli import write_mesh_scene

    scene = write_mesh_scene(tmp_path)
    code, err = run(capsys, scene, "--out", f"{tmp_path}/direct/", "--export-npz",
                    tmp_path / "t.npz", "--shader", "texture", *FAST)  # the uv seam shows
    assert code == 0, err
    assert "face_uv" in np.load(tmp_path / "t.npz").files
    code, err = run(capsys, "--from", tmp_path / "t.npz", "--out", f"{tmp_path}/again/",
                    "--shader", "texture", "-q")
    assert code == 0, err
    assert pngs(tmp_path / "again") == pngs(tmp_path / "direct")


AT = ["--size", "64x64", "--duration", "0.2", "--at", "0.08", "--quiet"]


def test_one_frame_of_a_framed_shot_is_drawn_as_its_run_drew_it(tmp_path, capsys):
    """--at draws one frame of a shot framed whole: the NPZ holds that frame and what
    framed the shot, so --from draws the same bytes; at another size, what a run at that
    size draws; a re-export keeps the record. Without it (an older NPZ) the one frame held
    is framed alone: another camera."""
    scene = write(tmp_path, "small.json", SMALL)
    code, err = run(capsys, scene, "--out", tmp_path / "direct.png", "--export-npz",
                    tmp_path / "at.npz", *AT)
    assert code == 0, err
    data = np.load(tmp_path / "at.npz")
    assert data["sim_frames"].tolist() == [7]
    assert data["framing_frames"].tolist() == [0, 4, 7, 11, 14]
    direct = (tmp_path / "direct.png").read_bytes()
    code, err = run(capsys, "--from", tmp_path / "at.npz", "--out", tmp_path / "again.png",
                    "--export-npz", tmp_path / "copy.npz", "-q")
    assert code == 0, err
    assert (tmp_path / "again.png").read_bytes() == direct
    copy = np.load(tmp_path / "copy.npz")
    for key in ("framing_frames", "framing_points"):
        assert np.array_equal(copy[key], data[key]), key
    code, err = run(capsys, "--from", tmp_path / "copy.npz", "--out", tmp_path / "copy.png",
                    "-q")
    assert code == 0, err
    assert (tmp_path / "copy.png").read_bytes() == direct
    # another size (and aspect): the camera a run at that size frames the whole shot with
    code, err = run(capsys, "--from", tmp_path / "at.npz", "--out", tmp_path / "wide.png",
                    "--size", "48x32", "--aa", "2", "-q")
    assert code == 0, err
    code, err = run(capsys, scene, "--out", tmp_path / "wide_direct.png", *AT, "--size",
                    "48x32", "--aa", "2")
    assert code == 0, err
    assert (tmp_path / "wide.png").read_bytes() == (tmp_path / "wide_direct.png").read_bytes()
    # the same shot asked for by its flags uses the record; the NPZ cannot frame another
    code, err = run(capsys, "--from", tmp_path / "at.npz", "--out", tmp_path / "flags.png",
                    "--at", "0.08", "--duration", "0.2", "-q")
    assert code == 0, err
    assert (tmp_path / "flags.png").read_bytes() == direct
    code, err = run(capsys, "--from", tmp_path / "at.npz", "--out", tmp_path / "x.png",
                    "--at", "0.08", "--duration", "0.1")
    assert code == 2 and "holds no frame at t = 0 s" in err, err
    with np.load(tmp_path / "at.npz") as d:
        older = {k: d[k] for k in d.files if not k.startswith("framing_")}
    np.savez_compressed(tmp_path / "older.npz", **older)
    code, err = run(capsys, "--from", tmp_path / "older.npz", "--out", tmp_path / "old.png",
                    "-q")
    assert code == 0, err
    assert (tmp_path / "old.png").read_bytes() != direct


def test_the_last_frame_of_a_shot_given_by_frames(tmp_path, capsys):
    """A .png of --frames 12 draws the last of the twelve, framed over all twelve (the
    cloth is lower in it than before, and bounces up: framed alone, another camera)."""
    scene = write(tmp_path, "small.json", SMALL)
    code, err = run(capsys, scene, "--out", tmp_path / "direct.png", "--export-npz",
                    tmp_path / "last.npz", "--frames", "12", "--size", "64x64", "-q")
    assert code == 0, err
    assert np.load(tmp_path / "last.npz")["sim_frames"].tolist() == [40]
    code, err = run(capsys, "--from", tmp_path / "last.npz", "--out", tmp_path / "again.png",
                    "-q")
    assert code == 0, err
    assert (tmp_path / "again.png").read_bytes() == (tmp_path / "direct.png").read_bytes()


def test_the_recorded_points_frame_as_all_points_at_any_size():
    """Framing.points: the camera of every point added, to the bit, at other sizes than
    the recording's: points along a line of equal x + a_x z (rounding decides their
    maximum), equal heights, repeated and rounded (tied) points."""
    from pipeline.view.framing import Framing

    rng = np.random.default_rng(7)
    a = Framing(48, 32).a_x
    z = np.linspace(-1.0, 1.0, 41)
    line = np.stack([0.3 - a * z, rng.normal(size=41), z], axis=1)
    grid = np.stack(np.meshgrid(np.linspace(-1, 1, 9), [0.5], np.linspace(-1, 1, 9)),
                    axis=-1).reshape(-1, 3)
    frames = [rng.normal(size=(200, 3)) for _ in range(4)]
    frames += [line, grid, grid, np.round(rng.normal(size=(300, 3)), 1)]
    recording = Framing(64, 64, record=True)
    for p in frames:
        recording.add(p)
    assert len(recording.points()) < 150
    for size in [(64, 64), (48, 32), (7, 500), (1920, 1080), (333, 217)]:
        every, recorded = Framing(*size), Framing(*size)
        for p in frames:
            every.add(p)
        recorded.add(recording.points())
        assert recorded.camera() == every.camera(), size


def test_a_malformed_framing_record_is_refused(shot, tmp_path, capsys):
    _, npz, _ = shot
    with np.load(npz) as d:
        arrays = {k: d[k] for k in d.files}
    np.savez(tmp_path / "bad.npz", **{**arrays, "framing_points": np.zeros((4, 2))})
    code, err = run(capsys, "--from", tmp_path / "bad.npz", "--out", tmp_path / "x.gif")
    assert code == 2 and "bad.npz: framing_frames, framing_points: expected" in err, err
    assert len(err.strip().splitlines()) == 1 and not (tmp_path / "x.gif").exists()


def test_an_older_npz_needs_its_scene_named(shot, tmp_path, capsys):
    """An NPZ from before the scene was recorded: drawn with the scene named; without it,
    one line saying so."""
    scene, npz, direct = shot
    with np.load(npz) as data:
        old = {k: data[k] for k in data.files if not k.startswith(("scene_", "npz_"))}
    np.savez_compressed(tmp_path / "old.npz", **old)
    code, err = run(capsys, scene, "--from", tmp_path / "old.npz", "--out",
                    f"{tmp_path}/again/", "--size", "64x64", "-q")
    assert code == 0, err
    assert pngs(tmp_path / "again") == pngs(direct)
    code, err = run(capsys, "--from", tmp_path / "old.npz", "--out", tmp_path / "x.gif")
    assert code == 2 and "old.npz: records no scene" in err and "SCENE.json --from" in err
    assert len(err.strip().splitlines()) == 1 and not (tmp_path / "x.gif").exists()


def test_an_export_from_a_from_run_records_the_scene_again(shot, tmp_path, capsys):
    _, npz, _ = shot
    code, err = run(capsys, "--from", npz, "--export-npz", tmp_path / "copy.npz", "-q")
    assert code == 0, err
    a, b = np.load(npz), np.load(tmp_path / "copy.npz")
    for key in a.files:
        assert np.array_equal(a[key], b[key]), key


def test_help_names_from(capsys):
    code, out = main(["--help"]), capsys.readouterr().out
    assert code == 0 and "--from SHOT.npz" in out


BAD_CLOTH = {**SMALL, "cloth": {**SMALL["cloth"], "num_width_points": 9}}


@pytest.mark.parametrize("argv, needle", [
    (["--from", "missing.npz", "--out", "x.gif"], "--from missing.npz: no such file"),
    (["--from", "garbage.npz", "--out", "x.gif"], "--from garbage.npz: is not an .npz file"),
    (["--from", "keys.npz", "--out", "x.gif"],
     "keys.npz: expected an .npz written by render --export-npz, with positions"),
    (["other.json", "--from", "shot.npz", "--out", "x.gif"],
     "holds a cloth of 64 points, but the cloth of other.json has 72"),
    (["--from", "shot.npz", "--out", "x.gif", "--set", "cloth.num_width_points=9"],
     "holds a cloth of 64 points"),
    (["--from", "shot.npz", "--out", "x.png", "--at", "1"], "holds no frame at t = 1 s"),
    (["--from", "shot.npz", "--out", "x.gif", "--duration", "0.5"], "holds no frame at t = 0.2 s"),
    (["--from", "shot.npz", "--out", "x.gif", "--fps", "30"], "simulator frame 3"),
    (["--from", "shot.npz", "--out", "x.gif", "--integrator", "rk4"], "--integrator: not with --from"),
    (["--from", "shot.npz", "--out", "x.gif", "--fidelity", "auto"], "--fidelity: not with --from"),
    (["--from", "shot.npz", "--out", "x.gif", "--contact", "robust"], "--contact: not with --from"),
    (["--from", "shot.npz", "--out", "x.gif", "--seed", "3"], "--seed: not with --from"),
    (["--from", "shot.npz", "--out", "x.gif", "--set", "simulation.frames_per_sec=60"],
     "--set simulation.frames_per_sec=60: not with --from"),
    (["--from", "shot.npz", "--out", "x.gif", "--export-npz", "./shot.npz"],
     "--export-npz ./shot.npz: the file --from reads"),
    (["--from", "shot.npz", "--out", "x.gif", "--workers", "2"], "--workers / --scheduler"),
    (["--from", "shot.npz", "--out", "x.gif", "--shader", "fancy"], "unknown shader"),
    (["--out", "x.gif"], "give the scene"),
])
def test_refusals(shot, tmp_path, capsys, monkeypatch, argv, needle):
    monkeypatch.chdir(tmp_path)
    (tmp_path / "garbage.npz").write_bytes(b"not a zip file")
    np.savez(tmp_path / "keys.npz", something=np.zeros(3))
    write(tmp_path, "other.json", BAD_CLOTH)
    before = files(tmp_path)
    code, err = run(capsys, *argv)
    assert code == 2, err
    assert needle in err, err
    assert err.startswith("render: ") and "Traceback" not in err
    hint = needle in ("unknown shader", "give the scene")  # plus "try 'render --help'"
    assert len(err.strip().splitlines()) == (2 if hint else 1), err
    assert files(tmp_path) == before  # nothing written

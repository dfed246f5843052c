"""The `render` command end to end: in-process through main(argv), plus real subprocesses.

The renderer (`pipeline.run.frames`, `shading`) may still be missing while it is written; the
`env` fixture then installs small stand-ins through monkeypatch, for these tests only.
With the real modules present the same tests run against them.
"""
from __future__ import annotations

import importlib
import json
import os
import re
import shutil
import subprocess
import sys
import types
from pathlib import Path

import numpy as np
import pytest
from PIL import Image

from pipeline.cli import main

from conftest import child_env
from pipeline.cli.messages import Errors
from pipeline.cli.render import _pipeline_mode, _pipelined, nearest_sim_frames, output_times, queue_depth

ROOT = Path(__file__).resolve().parents[1]

SMALL = {
    "cloth": {"width": 1, "height": 1, "num_width_points": 10, "num_height_points": 10,
              "thickness": 0.0095, "orientation": 0, "damping": 0.2, "density": 150.0,
              "ks": 5000.0, "enable_structural": True, "enable_shearing": True,
              "enable_bending": True},
    "sphere": {"origin": [0.5, 0.2, 0.5], "radius": 0.2, "friction": 0.3},
    "plane": {"point": [0, 0, 0], "normal": [0, 1, 0], "friction": 0.5},
}
FAST = ["--size", "64x64", "--duration", "0.2", "--quiet"]


# ---------------------------------------------------------------- stand-ins for the renderer


def _real(modname, attrs):
    try:
        mod = importlib.import_module(modname)
    except ImportError:
        return None
    return mod if all(hasattr(mod, a) for a in attrs) else None


def _fake_shading():
    shading = types.ModuleType("shading")
    shading.SHADERS = ("normal", "wireframe", "diffuse", "phong", "texture", "bump",
                       "displacement", "mirror", "toon")

    class TextureError(ValueError):
        pass

    shading.TextureError = TextureError
    testing = types.ModuleType("shading.testing")

    def assert_image_close(actual, expected, atol=2, diff_path=None):
        a, b = np.asarray(actual, int), np.asarray(expected, int)
        if a.shape != b.shape:
            raise AssertionError(f"shape {a.shape} != {b.shape}")
        worst = np.abs(a - b).max()
        if worst > atol:
            if diff_path is not None:
                Image.fromarray(np.clip(np.abs(a - b) * 8, 0, 255).astype(np.uint8)).save(diff_path)
            raise AssertionError(f"max difference {worst} > {atol}; diff image: {diff_path}")

    testing.assert_image_close = assert_image_close
    shading.testing = testing
    return shading, testing


def _fake_frames(shading):
    from pipeline.scene import Plane, Sphere

    frames = types.ModuleType("pipeline.run.frames")

    def grid(nw, nh):
        tris = []
        for i in range(nh - 1):
            for j in range(nw - 1):
                A, B, C, D = i * nw + j, i * nw + j + 1, (i + 1) * nw + j, (i + 1) * nw + j + 1
                tris += [(A, C, B), (B, C, D)]
        i, j = np.mgrid[0:nh, 0:nw]
        return np.array(tris), np.stack([j.ravel() / (nw - 1), i.ravel() / (nh - 1)], 1)

    def mesh(pos, tris, uv):
        return types.SimpleNamespace(positions=pos, normals=np.tile([0.0, 1.0, 0.0], (len(pos), 1)),
                                     uvs=uv, triangles=tris)

    def scene_meshes(scene, positions, model):
        tris, uv = grid(model.nw, model.nh)
        out = [mesh(np.asarray(positions, float), tris, uv)]
        t4, uv4 = grid(2, 2)
        for kind in (Sphere, Plane):
            for c in scene.colliders:
                if isinstance(c, kind):
                    o = np.array(c.origin if kind is Sphere else c.point, float)
                    out.append(mesh(o + [[-1, 0, -1], [1, 0, -1], [-1, 0, 1], [1, 0, 1]],
                                    t4, uv4))
        return out

    def render_frame(scene, positions, model, shader=None, width=None, height=None, aa=None,
                     time=0.0, shot=None):
        shader = shader or scene.render.shader
        if shader not in shading.SHADERS:
            raise ValueError(shader)
        if shader == "texture" and scene.render.texture and not Path(scene.render.texture).exists():
            raise shading.TextureError(f"cannot read texture {scene.render.texture}")
        w, h = width or scene.render.width, height or scene.render.height
        img = np.empty((h, w, 3), np.uint8)
        img[:] = (51, 64, 77)
        p = np.asarray(positions)
        x = np.clip(((p[:, 0] + 0.2) / 1.4 * w).astype(int), 0, w - 1)
        y = np.clip(((1.3 - p[:, 1]) / 1.4 * h).astype(int), 0, h - 1)
        img[y, x] = (200, 40 * shading.SHADERS.index(shader) % 256, 100)
        return img

    frames.scene_meshes = scene_meshes
    frames.render_frame = render_frame
    return frames


@pytest.fixture
def env(monkeypatch):
    """'real' when the renderer is importable, else installs stand-ins ('fake')."""
    shading = _real("shading", ["SHADERS", "TextureError"])
    testing = _real("shading.testing", ["assert_image_close"])
    frames = _real("pipeline.run.frames", ["render_frame", "scene_meshes"])
    if shading and testing and frames:
        return "real"
    if not shading:
        shading, testing = _fake_shading()
        monkeypatch.setitem(sys.modules, "shading", shading)
        monkeypatch.setitem(sys.modules, "shading.testing", testing)
    elif not testing:
        testing = _fake_shading()[1]
        monkeypatch.setitem(sys.modules, "shading.testing", testing)
        monkeypatch.setattr(shading, "testing", testing, raising=False)
    if not frames:
        frames = _fake_frames(shading)
        monkeypatch.setitem(sys.modules, "pipeline.run.frames", frames)
    return "fake"


@pytest.fixture
def scene(tmp_path):
    path = tmp_path / "small.json"
    path.write_text(json.dumps(SMALL))
    return path


def run(capsys, *argv):
    code = main([str(a) for a in argv])
    out, err = capsys.readouterr()
    return code, out, err


def files(d):
    return sorted(p.name for p in Path(d).iterdir())


# ---------------------------------------------------------------- outputs end to end


def test_gif(env, scene, tmp_path, capsys):
    out = tmp_path / "cloth.gif"
    code, _, err = run(capsys, scene, "--shader", "phong", "--out", out, *FAST)
    assert code == 0, err
    assert err == ""  # --quiet: nothing at all
    with Image.open(out) as im:
        assert im.n_frames == 5 and im.size == (64, 64)
        assert im.info["loop"] == 0
        durations = []
        for i in range(im.n_frames):
            im.seek(i)
            durations.append(im.info["duration"])
    assert durations == [40] * 5
    assert files(tmp_path) == ["cloth.gif", "small.json"]


def test_gif_fps_and_frames(env, scene, tmp_path, capsys):
    out = tmp_path / "c.gif"
    code, _, err = run(capsys, scene, "--out", out, "--frames", "6", "--fps", "30",
                       "--size", "32x24", "-q")
    assert code == 0, err
    with Image.open(out) as im:
        assert im.n_frames == 6 and im.size == (32, 24)
        d = []
        for i in range(6):
            im.seek(i)
            d.append(im.info["duration"])
    assert sum(d) == 200 and set(d) <= {30, 40}


def test_mp4(env, scene, tmp_path, capsys):
    import imageio_ffmpeg

    out = tmp_path / "c.mp4"
    code, _, err = run(capsys, scene, "--out", out, "--duration", "0.2", "--size", "63x47")
    assert code == 0, err
    assert "padded to 64x48" in err  # odd sizes are padded, and said so
    gen = imageio_ffmpeg.read_frames(str(out))
    meta = next(gen)
    assert tuple(meta["size"]) == (64, 48) and meta["fps"] == pytest.approx(30)
    assert sum(1 for _ in gen) == 6
    assert files(tmp_path) == ["c.mp4", "small.json"]


def test_png_last_and_folder(env, scene, tmp_path, capsys):
    png = tmp_path / "last.png"
    assert run(capsys, scene, "--out", png, *FAST)[0] == 0
    folder = tmp_path / "frames"
    assert run(capsys, scene, "--out", f"{folder}/", *FAST)[0] == 0
    names = files(folder)
    assert names == [f"frame_{i:05d}.png" for i in range(5)]
    last = np.asarray(Image.open(folder / names[-1]))
    assert last.shape == (64, 64, 3)
    np.testing.assert_array_equal(np.asarray(Image.open(png)), last)
    first = np.asarray(Image.open(folder / names[0]))
    assert not np.array_equal(first, last)  # the cloth moved
    # an existing folder is a folder output too, without the trailing '/'
    assert run(capsys, scene, "--out", folder, *FAST[:2], "--frames", "2", "-q")[0] == 0
    assert files(folder) == ["frame_00000.png", "frame_00001.png"]
    # a two-frame shot is framed on its own (pipeline.view.framing): its --at 0 PNG is frame 0
    assert run(capsys, scene, "--out", png, *FAST[:2], "--frames", "2", "--at", "0", "-q"
               )[0] == 0
    np.testing.assert_array_equal(np.asarray(Image.open(folder / "frame_00000.png")),
                                  np.asarray(Image.open(png)))


def test_png_at(env, scene, tmp_path, capsys):
    a = tmp_path / "a.png"
    b = tmp_path / "b.png"
    """--at T is frame T of the animation the same flags make (one framing: its shot)."""
    assert run(capsys, scene, "--out", a, "--at", "0.08", *FAST)[0] == 0
    assert run(capsys, scene, "--out", f"{tmp_path}/f/", *FAST)[0] == 0
    np.testing.assert_array_equal(np.asarray(Image.open(a)),
                                  np.asarray(Image.open(tmp_path / "f/frame_00002.png")))
    assert run(capsys, scene, "--out", b, "--at", "0", *FAST)[0] == 0
    np.testing.assert_array_equal(np.asarray(Image.open(b)),
                                  np.asarray(Image.open(tmp_path / "f/frame_00000.png")))


def test_exports(env, scene, tmp_path, capsys):
    import trimesh

    objs, npz = tmp_path / "objs", tmp_path / "pos.npz"
    code, _, err = run(capsys, scene, "--out", tmp_path / "c.gif", "--export-obj", objs,
                       "--export-npz", npz, *FAST)
    assert code == 0, err
    assert files(objs) == [f"frame_{i:05d}.obj" for i in range(5)]
    data = np.load(npz)
    assert data["positions"].shape == (5, 100, 3)
    np.testing.assert_allclose(data["times"], np.arange(5) / 25)
    np.testing.assert_array_equal(data["sim_frames"], [0, 4, 7, 11, 14])  # 90 Hz, nearest
    assert data["faces"].shape == (162, 3) and data["uv"].shape == (100, 2)
    np.testing.assert_allclose(data["sim_times"], data["sim_frames"] / 90)
    s = trimesh.load(objs / "frame_00004.obj", force="scene", process=False,
                     split_objects=True)
    assert set(s.geometry) == {"cloth", "sphere_0", "plane_0"}
    cloth = s.geometry["cloth"]
    np.testing.assert_allclose(cloth.vertices, data["positions"][4], rtol=1e-8, atol=1e-9)
    np.testing.assert_array_equal(cloth.faces, data["faces"])
    assert cloth.visual.uv.shape == (100, 2)


def test_exports_only(env, scene, tmp_path, capsys):
    code, _, err = run(capsys, scene, "--export-npz", tmp_path / "p.npz", "--frames", "3", "-q")
    assert code == 0, err
    assert np.load(tmp_path / "p.npz")["positions"].shape == (3, 100, 3)


def test_serial_and_pipelined_identical(env, scene, tmp_path, capsys):
    a, b = tmp_path / "a.gif", tmp_path / "b.gif"
    assert run(capsys, scene, "--out", a, *FAST)[0] == 0
    for mode in ("serial", "overlap", "split"):
        assert run(capsys, scene, "--out", b, "--pipeline", mode, *FAST)[0] == 0
        assert a.read_bytes() == b.read_bytes()


@pytest.mark.parametrize("layer, framed, expected", [
    ("omp", False, "split"),  # simulate and render at once: one core each
    ("omp", True, "overlap"),  # the whole shot is simulated first: every core for each
    ("workqueue", True, "serial"),  # not thread-safe: never two parallel kernels at once
])
def test_auto_pipeline_mode(monkeypatch, layer, framed, expected):
    import numba

    monkeypatch.setattr(numba, "threading_layer", lambda: layer)
    assert _pipeline_mode("auto", framed=framed) == expected
    assert _pipeline_mode("split", framed=framed) == ("serial" if layer == "workqueue"
                                                          else "split")


@pytest.mark.skipif(__import__("numba").config.NUMBA_NUM_THREADS < 2, reason="needs 2 threads")
def test_split_pipeline_draws_on_every_free_core_once_every_frame_is_simulated(monkeypatch):
    import time

    import numba

    import clothjit

    # two free cores (the count is chosen once per process, from the load: clothjit.THREADS)
    monkeypatch.setattr(clothjit, "THREADS", 2)
    seen = []

    def consume(k, pos):
        seen.append(numba.get_num_threads())
        time.sleep(0.01)

    before = numba.get_num_threads()
    # 10 frames through a 4-frame queue: the first is drawn while 5 are still to come
    _pipelined(((k, None) for k in range(10)), consume, depth=4, threads_per_stage=1)
    assert seen[0] == 1 and seen[-1] == 2
    assert numba.get_num_threads() == before
    # the simulation may run 32 MB of positions ahead (the README's cloth: 559 frames)
    assert queue_depth(2500 * 3 * 8) == 559 and queue_depth(1 << 30) == 4


def test_summary_line(env, scene, tmp_path, capsys):
    code, out, err = run(capsys, scene, "--out", tmp_path / "c.gif", "--size", "64x64",
                         "--duration", "0.2")
    assert code == 0
    assert out == ""
    lines = err.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("render: 5 frames 64x64")
    for word in ("simulate", "render", "encode", "c.gif"):
        assert word in lines[0]
    assert re.search(r"c\.gif \(\d+(\.\d)? (B|KB)\);", lines[0])


def test_overrides_and_seed(env, scene, tmp_path, capsys):
    npz = tmp_path / "p.npz"
    # self-collision off: on (its "auto" for a vertical cloth) the stepping kernel is
    # compiled for this test alone
    code, _, err = run(capsys, scene, "--export-npz", npz, "--frames", "1", "-q",
                       "--set", "cloth.num_width_points=4", "--set", "cloth.orientation=1",
                       "--set", "simulation.self_collision=false",
                       "--seed", "7", "--integrator", "verlet")
    assert code == 0, err
    p = np.load(npz)["positions"]
    assert p.shape == (1, 40, 3) and np.abs(p[0, :, 2]).max() <= 0.001


# ---------------------------------------------------------------- help, version


def test_help_lists_shaders(env, capsys):
    code, out, _ = run(capsys, "--help")
    assert code == 0
    import shading

    for name in shading.SHADERS:
        assert name in out
    for flag in ("--out", "--duration", "--frames", "--fps", "--size", "--aa", "--seed", "--set",
                 "--integrator", "--export-obj", "--export-npz", "--check", "--at", "--quiet",
                 "--debug", "--version"):
        assert flag in out


def test_version(capsys):
    code, out, _ = run(capsys, "--version")
    assert code == 0 and out.startswith("render (clothpipe) ")


def test_the_cli_shader_list_is_the_renderers():
    from pipeline.cli.options import shader_names
    from shading import REGISTRY

    assert sorted(shader_names()) == sorted(REGISTRY)


@pytest.mark.parametrize("flag", ["--help", "--version"])
def test_help_and_version_load_no_numba(flag, tmp_path):
    code = ("import sys; from pipeline.cli import main\n"
            "try:\n    main(sys.argv[1:])\nexcept SystemExit:\n    pass\n"
            "assert 'numba' not in sys.modules, 'numba was imported'")
    r = subprocess.run([sys.executable, "-c", code, flag], cwd=tmp_path, env=child_env(),
                       capture_output=True, text=True, timeout=120)
    assert r.returncode == 0, r.stderr


# ---------------------------------------------------------------- bad input: exit 2


@pytest.mark.parametrize("argv,needle", [
    (["--out", "x.gif", "--size", "0x3"], "--size"),
    (["--out", "x.gif", "--size", "big"], "--size"),
    (["--out", "x.gif", "--fps", "-1"], "--fps"),
    (["--out", "x.gif", "--fps", "60"], "at most 50"),
    (["--out", "x.gif", "--frames", "0"], "--frames"),
    (["--out", "x.gif", "--frames", "3", "--duration", "1"], "not allowed with"),
    (["--out", "x.gif", "--aa", "0"], "--aa"),
    (["--out", "x.gif", "--bogus"], "unrecognized"),
    (["--out", "x.gif", "--at", "1"], "--at needs a .png"),
    (["--out", "x.mp4", "--check", "g.png"], "--check needs a .png"),
    (["--out", "x.jpg"], "unknown output type"),
    (["--out", "x.gif", "--set", "novalue"], "--set"),
    (["--out", "x.gif", "--shader", "fancy"], "unknown shader 'fancy'"),
    (["--out", "x.gif", "--set", "cloth.width=-1"], "cloth"),
    (["--out", "x.gif", "--integrator", "magic"], "magic"),
    (["--out", "x.png", "--check", "missing.png"], "missing.png"),
    (["--out", "x.gif", "--export-npz", "p.txt"], ".npz"),
    ([], "give --out"),
])
def test_bad_flags(env, scene, tmp_path, capsys, monkeypatch, argv, needle):
    monkeypatch.chdir(tmp_path)
    code, out, err = run(capsys, scene, *argv)
    assert code == 2, err
    assert needle in err
    assert err.startswith("render: ") and "Traceback" not in err
    assert len(err.strip().splitlines()) <= 2
    assert files(tmp_path) == ["small.json"]  # nothing written


def test_bad_scene(env, tmp_path, capsys):
    bad = tmp_path / "bad.json"
    bad.write_text('{"cloth": {"width": 1}}')
    out = tmp_path / "c.gif"
    code, _, err = run(capsys, bad, "--out", out)
    assert code == 2 and err.startswith("render: ") and "bad.json" in err
    assert "Traceback" not in err
    assert files(tmp_path) == ["bad.json"]
    code, _, err = run(capsys, tmp_path / "missing.json", "--out", out)
    assert code == 2 and "missing.json" in err
    (tmp_path / "notjson.json").write_text("{nope")
    assert run(capsys, tmp_path / "notjson.json", "--out", out)[0] == 2
    assert not out.exists()


@pytest.mark.skipif(not (ROOT / "tests/bad_scenes").is_dir(), reason="no bad scenes yet")
def test_bad_scene_corpus(env, tmp_path, capsys):
    for bad in sorted((ROOT / "tests/bad_scenes").glob("*.json"))[:8]:
        code, _, err = run(capsys, bad, "--out", tmp_path / "c.gif", "--frames", "1")
        assert code == 2, (bad.name, err)
        assert err.startswith("render: ") and "Traceback" not in err
    assert files(tmp_path) == []


@pytest.mark.parametrize("name", ["mesh_file_missing", "mesh_not_watertight",
                                  "keyframes_out_of_order", "mass_map_image_missing"])
def test_bad_scene_files_it_names(env, tmp_path, capsys, name):
    """Scene keys that name files or order keyframes: exit 2, one line, nothing written."""
    bad = ROOT / "tests" / "bad_scenes" / f"{name}.json"
    code, _, err = run(capsys, bad, "--out", tmp_path / "c.gif", "--frames", "1")
    assert code == 2 and err.startswith("render: ") and f"{name}.json: " in err
    assert "Traceback" not in err and len(err.strip().splitlines()) == 1
    assert files(tmp_path) == []


def test_debug_shows_traceback(env, tmp_path, capsys):
    bad = tmp_path / "bad.json"
    bad.write_text("[]")
    code, _, err = run(capsys, bad, "--out", tmp_path / "c.gif", "--debug")
    assert code == 2 and "Traceback" in err and "render: " in err


@pytest.mark.parametrize("kind", ["missing_dir", "parent_is_file", "target_is_dir"])
def test_unwritable_output(env, scene, tmp_path, capsys, kind):
    (tmp_path / "afile").write_text("x")
    (tmp_path / "adir.gif").mkdir()
    out = {"missing_dir": tmp_path / "nope" / "c.gif",
           "parent_is_file": tmp_path / "afile" / "c.gif",
           "target_is_dir": tmp_path / "adir.gif"}[kind]
    before = files(tmp_path)
    if kind == "target_is_dir":  # an existing folder is a folder output: fine
        assert run(capsys, scene, "--out", out, *FAST)[0] == 0
        return
    code, _, err = run(capsys, scene, "--out", out, *FAST)
    assert code == 2 and err.startswith("render: cannot write")
    assert files(tmp_path) == before


@pytest.mark.skipif(os.geteuid() == 0, reason="root can write anywhere")
def test_readonly_dir(env, scene, tmp_path, capsys):
    ro = tmp_path / "ro"
    ro.mkdir()
    ro.chmod(0o500)
    try:
        code, _, err = run(capsys, scene, "--out", ro / "c.gif", *FAST)
    finally:
        ro.chmod(0o700)
    assert code == 2 and "cannot write" in err


def test_readonly_filesystem(env, scene, capsys):
    if not os.path.isdir("/proc/self"):
        pytest.skip("no /proc")
    code, _, err = run(capsys, scene, "--out", "/proc/self/c.gif", *FAST)
    assert code == 2 and err.startswith("render: cannot write")


def test_missing_texture(env, scene, tmp_path, capsys):
    code, _, err = run(capsys, scene, "--out", tmp_path / "c.png", "--shader", "texture",
                       "--set", "render.texture=nowhere.png", *FAST)
    assert code == 2, err
    assert "nowhere.png" in err and "Traceback" not in err
    assert files(tmp_path) == ["small.json"]


# ---------------------------------------------------------------- failures: exit 1 / 130


@pytest.mark.parametrize("out", ["c.gif", "c.mp4", "frames/", "c.png"])
def test_interrupt_leaves_nothing(env, scene, tmp_path, capsys, monkeypatch, out):
    from pipeline.simulation import Simulation

    real = Simulation.advance
    calls = {"n": 0}

    def advance(self, frames=1):
        calls["n"] += 1
        if calls["n"] == 12:
            raise KeyboardInterrupt
        return real(self, frames)

    monkeypatch.setattr(Simulation, "advance", advance)
    code, _, err = run(capsys, scene, "--out", f"{tmp_path}/{out}", "--export-obj", tmp_path / "objs",
                       "--export-npz", tmp_path / "p.npz", "--size", "64x64", "--duration", "1")
    assert code == 130 and "interrupted" in err
    assert files(tmp_path) == ["small.json"]


def test_render_failure_in_worker(env, scene, tmp_path, capsys, monkeypatch):
    frames = sys.modules.get("pipeline.run.frames") or importlib.import_module("pipeline.run.frames")
    real = frames.render_frame
    calls = {"n": 0}

    def render_frame(*a, **k):
        calls["n"] += 1
        if calls["n"] == 3:
            raise RuntimeError("boom")
        return real(*a, **k)

    monkeypatch.setattr(frames, "render_frame", render_frame)
    code, _, err = run(capsys, scene, "--out", tmp_path / "c.gif", *FAST)
    assert code == 1
    assert err.startswith("render: internal error: RuntimeError: boom")
    assert "--debug" in err and "Traceback" not in err
    assert files(tmp_path) == ["small.json"]


def test_divergence(env, scene, tmp_path, capsys, monkeypatch):
    from pipeline.physics.errors import DivergenceError
    from pipeline.simulation import Simulation

    def advance(self, frames=1):
        raise DivergenceError("simulation diverged at frame 3, step 7 of 30 (t = 0.03 s): "
                              "positions became non-finite")

    monkeypatch.setattr(Simulation, "advance", advance)
    code, _, err = run(capsys, scene, "--out", tmp_path / "c.gif", *FAST)
    assert code == 1
    assert err.strip() == ("render: simulation diverged at frame 3, step 7 of 30 (t = 0.03 s): "
                           "positions became non-finite")
    assert files(tmp_path) == ["small.json"]


# ---------------------------------------------------------------- --check


def test_check_pass_and_fail(env, scene, tmp_path, capsys, monkeypatch):
    golden = tmp_path / "golden.png"
    assert run(capsys, scene, "--out", golden, *FAST)[0] == 0
    out = tmp_path / "out.png"
    assert run(capsys, scene, "--out", out, "--check", golden, *FAST)[0] == 0
    assert not (tmp_path / "out.diff.png").exists()
    img = np.asarray(Image.open(golden)).copy()
    img[10:20, 10:20] = 255 - img[10:20, 10:20]
    Image.fromarray(img).save(golden)
    monkeypatch.chdir(tmp_path)
    code, _, err = run(capsys, scene, "--out", out, "--check", golden, *FAST)
    assert code == 3
    assert err.startswith("render: --check") and "out.diff.png" in err
    diff = np.asarray(Image.open(tmp_path / "out.diff.png"))
    w = 64
    if diff.shape[1] == 3 * w:  # shading.testing writes actual | golden | 8x difference
        diff = diff[:, 2 * w:]
    assert diff[10:20, 10:20].max() > 0 and diff[30:, 30:].max() == 0
    assert out.exists()
    assert len(err.strip().splitlines()) == 1
    assert not (tmp_path / "tests").exists()  # no stray diff elsewhere
    # passing again removes the stale diff image
    Image.fromarray(np.asarray(Image.open(out))).save(golden)
    assert run(capsys, scene, "--out", out, "--check", golden, *FAST)[0] == 0
    assert not (tmp_path / "out.diff.png").exists()


def test_check_size_mismatch(env, scene, tmp_path, capsys):
    golden = tmp_path / "golden.png"
    Image.fromarray(np.zeros((10, 12, 3), np.uint8)).save(golden)
    code, _, err = run(capsys, scene, "--out", tmp_path / "o.png", "--check", golden, *FAST)
    assert code == 3 and "o.diff.png" in err


# ---------------------------------------------------------------- pipeline plan


def test_nearest_sim_frames():
    times = output_times(6, 25)
    assert nearest_sim_frames(times, 90) == [0, 4, 7, 11, 14, 18]
    assert nearest_sim_frames(output_times(4, 30), 90) == [0, 3, 6, 9]
    assert nearest_sim_frames([0.5 / 90], 90) == [1]  # ties go to the later frame


# ---------------------------------------------------------------- real subprocesses


def _render_cmd():
    exe = shutil.which("render")
    if exe:
        return [exe]
    return [sys.executable, "-m", "pipeline.cli"]


@pytest.fixture
def real_env(env):
    if env != "real":
        pytest.skip("renderer not available yet (subprocesses cannot use stand-ins)")


def test_subprocess_gif(real_env, scene, tmp_path):
    out = tmp_path / "c.gif"
    r = subprocess.run(_render_cmd() + [str(scene), "--shader", "phong", "--out", str(out),
                                        "--size", "64x64", "--duration", "0.2"],
                       capture_output=True, text=True, timeout=600, cwd=tmp_path)
    assert r.returncode == 0, r.stderr
    assert r.stdout == ""
    assert r.stderr.startswith("render: 5 frames 64x64 phong")  # stderr not a tty: no bars
    assert Image.open(out).n_frames == 5


def test_subprocess_errors(real_env, scene, tmp_path):
    r = subprocess.run(_render_cmd() + [str(scene), "--out", str(tmp_path / "x.gif"),
                                        "--shader", "nope"],
                       capture_output=True, text=True, timeout=600)
    assert r.returncode == 2
    assert r.stderr.startswith("render: unknown shader 'nope'")
    assert "Traceback" not in r.stderr
    r = subprocess.run(_render_cmd() + ["--version"], capture_output=True, text=True, timeout=600)
    assert r.returncode == 0 and "clothpipe" in r.stdout


class _TTY:
    """A fake terminal for stderr."""

    def __init__(self):
        import io

        self.buf = io.StringIO()

    def isatty(self):
        return True

    def write(self, s):
        return self.buf.write(s)

    def flush(self):
        pass


def test_progress_bars_on_a_terminal_only(env, scene, tmp_path, monkeypatch):
    tty = _TTY()
    monkeypatch.setattr(sys, "stderr", tty)
    assert main([str(scene), "--out", str(tmp_path / "a.gif"), "--size", "32x32",
                 "--duration", "0.2"]) == 0
    text = tty.buf.getvalue()
    assert "simulate" in text and "render" in text and "frame/s" in text  # tqdm bars
    assert "render: 5 frames" in text.rstrip().splitlines()[-1]
    tty = _TTY()
    monkeypatch.setattr(sys, "stderr", tty)
    assert main([str(scene), "--out", str(tmp_path / "b.gif"), "--size", "32x32",
                 "--duration", "0.2", "--quiet"]) == 0
    assert tty.buf.getvalue() == ""


def test_bars_show_on_a_terminal_that_reports_no_width():
    """A pseudo-terminal nobody sized (`script` run without a terminal of its own) reports
    0 columns: tqdm, left to follow that width, drew nothing at all."""
    leader, follower = os.openpty()  # 0 x 0 until someone sets its size
    try:
        code = ("from pipeline.run.progress import bar, counter\n"
                "b = bar(3, 'compile', 'kernel', True); b.update(3); b.close()\n"
                "c = counter('compile', 'kernel', True); c.update(2); c.close()\n")
        subprocess.run([sys.executable, "-c", code], stderr=follower, env=child_env(),
                       check=True, timeout=60)
        os.close(follower)
        follower = None
        out = b""
        while True:
            try:
                chunk = os.read(leader, 65536)
            except OSError:  # EIO: the writer is gone
                break
            if not chunk:
                break
            out += chunk
    finally:
        os.close(leader)
        if follower is not None:
            os.close(follower)
    text = out.decode(errors="replace")
    assert re.search(r"compile +0%\|.*\| 0/3 \[", text), text  # the bar as it starts
    assert re.search(r"compile +0 kernels \[", text), text  # the count as it starts


def test_a_message_under_a_bar_starts_on_a_cleared_line(monkeypatch):
    """A message said while a bar is on screen (a stability warning during the first run's
    compile) blanks the bar's line first and draws the bar again below: printed as is, it
    went on after the bar ("... 12/12 [00:18<00:00, 1.59s/kernel]render: warning: ...")."""
    from pipeline.run.progress import bar

    tty = _TTY()
    monkeypatch.setattr(sys, "stderr", tty)
    kernels = bar(5, "compile", "kernel", True)
    kernels.update(2)
    Errors(sys.stderr, quiet=False, debug=False).warn("a warning")
    kernels.close()
    text = tty.buf.getvalue()
    before, after = text.split("render: warning: a warning\n")
    assert "compile" in before and before.endswith("\r")  # the bar, then its line blanked
    assert "2/5" in after  # drawn again

"""Output writers: formats read back, durations, palettes, atomicity."""
from __future__ import annotations

import gc
import os
import warnings
from types import SimpleNamespace

import numpy as np
import pytest
from PIL import Image

from pipeline.run import outputs
from pipeline.run.outputs import FolderWriter, GifWriter, Mp4Writer, NpzWriter, ObjWriter, OutputError, PngWriter, classify_output, gif_delays_cs


def frames(n=6, h=40, w=48, seed=0):
    """Smooth moving gradients (many colours) plus a flat background."""
    ys, xs = np.mgrid[0:h, 0:w]
    out = []
    for k in range(n):
        img = np.empty((h, w, 3), np.uint8)
        img[..., 0] = (xs * 255 // (w - 1) + 10 * k) % 256
        img[..., 1] = ys * 255 // (h - 1)
        img[..., 2] = 77
        img[: h // 4] = (51, 64, 77)  # background band
        out.append(img)
    return out


def listing(d):
    return sorted(p.name for p in d.iterdir())


def gif_info(path):
    with Image.open(path) as im:
        durations, loops = [], im.info.get("loop")
        rgb = []
        for i in range(im.n_frames):
            im.seek(i)
            durations.append(im.info["duration"])
            rgb.append(np.asarray(im.convert("RGB")))
        return SimpleNamespace(n=im.n_frames, durations=durations, loop=loops,
                               size=im.size, frames=rgb)


# ------------------------------------------------------------------ paths


@pytest.mark.parametrize("text,kind", [("a.gif", "gif"), ("A.GIF", "gif"), ("x/y.mp4", "mp4"),
                                       ("f.png", "png"), ("dir/", "dir")])
def test_classify(text, kind):
    assert classify_output(text)[0] == kind


def test_classify_existing_dir(tmp_path):
    assert classify_output(str(tmp_path))[0] == "dir"


@pytest.mark.parametrize("text", ["a.jpg", "noext", "a.gif.txt", ""])
def test_classify_rejects(text):
    with pytest.raises(OutputError):
        classify_output(text)


def test_missing_parent_is_output_error(tmp_path):
    with pytest.raises(OutputError, match="does not exist"):
        PngWriter(tmp_path / "nope" / "a.png")
    with pytest.raises(OutputError, match="does not exist"):
        FolderWriter(tmp_path / "nope" / "frames")


def test_parent_is_a_file(tmp_path):
    (tmp_path / "file").write_text("x")
    with pytest.raises(OutputError):
        GifWriter(tmp_path / "file" / "a.gif")


def test_target_is_a_directory(tmp_path):
    (tmp_path / "d.png").mkdir()
    with pytest.raises(OutputError, match="directory"):
        PngWriter(tmp_path / "d.png")


# ------------------------------------------------------------------ GIF


def test_gif_delays_exact_total():
    assert gif_delays_cs(5, 25) == [4] * 5
    assert gif_delays_cs(4, 50) == [2] * 4
    d = gif_delays_cs(90, 30)
    assert set(d) == {3, 4} and sum(d) == 300
    d = gif_delays_cs(7, 12)
    assert sum(d) == round(700 / 12)


@pytest.mark.parametrize("palette", ["global", "frame"])
@pytest.mark.parametrize("dither", ["none", "fs", "stable"])
def test_gif_roundtrip(tmp_path, palette, dither):
    fr = frames()
    path = tmp_path / "a.gif"
    with GifWriter(path, fps=25, palette=palette, dither=dither) as w:
        for f in fr:
            w.add(f)
    info = gif_info(path)
    assert info.n == len(fr)
    assert info.size == (48, 40)
    assert info.durations == [40] * len(fr)
    assert info.loop == 0  # loops forever
    for got, want in zip(info.frames, fr):
        err = np.abs(got.astype(int) - want).mean()
        assert err < 6, err
        # the flat background survives exactly
        assert (got[:10] == (51, 64, 77)).all()
    assert listing(tmp_path) == ["a.gif"]  # spool and temp files gone


def test_gif_stable_dither_static_pixels(tmp_path):
    """Pixels that do not change in the source never change in the GIF."""
    fr = frames(5, 40, 48)
    for f in fr:
        f[20:, :24] = fr[0][20:, :24]  # a static block with a gradient
    path = tmp_path / "a.gif"
    with GifWriter(path, fps=25) as w:
        for f in fr:
            w.add(f)
    got = gif_info(path).frames
    for g in got[1:]:
        np.testing.assert_array_equal(g[20:, :24], got[0][20:, :24])


def test_gif_few_colours_exact(tmp_path):
    rng = np.random.default_rng(1)
    pal = rng.integers(0, 256, (50, 3), dtype=np.uint8)
    fr = [pal[rng.integers(0, 50, (20, 30))] for _ in range(3)]
    path = tmp_path / "a.gif"
    with GifWriter(path, fps=10) as w:
        for f in fr:
            w.add(f)
    info = gif_info(path)
    for got, want in zip(info.frames, fr):
        np.testing.assert_array_equal(got, want)
    assert info.durations == [100, 100, 100]


def test_gif_identical_frames_keep_count_and_delays(tmp_path):
    f = frames(1)[0]
    fr = [f, f, f, frames(2)[1], frames(2)[1]]
    path = tmp_path / "a.gif"
    with GifWriter(path, fps=30) as w:
        for x in fr:
            w.add(x)
    info = gif_info(path)
    assert info.n == 5
    assert sum(info.durations) == 170 and set(info.durations) <= {30, 40}
    for got, want in zip(info.frames, fr):
        assert np.abs(got.astype(int) - want).mean() < 6


def test_gif_fps_limit(tmp_path):
    with pytest.raises(OutputError, match="at most 50"):
        GifWriter(tmp_path / "a.gif", fps=60)
    assert listing(tmp_path) == []


def test_gif_abort_leaves_nothing(tmp_path):
    w = GifWriter(tmp_path / "a.gif")
    w.add(frames(1)[0])
    w.add(frames(2)[1])
    assert len(listing(tmp_path)) == 2  # temp file + frame spool
    w.abort()
    assert listing(tmp_path) == []


def test_context_manager_error_leaves_nothing(tmp_path):
    with pytest.raises(KeyboardInterrupt):
        with GifWriter(tmp_path / "a.gif", palette="frame") as w:
            w.add(frames(1)[0])
            raise KeyboardInterrupt
    assert listing(tmp_path) == []


def test_frame_size_change_rejected(tmp_path):
    w = GifWriter(tmp_path / "a.gif")
    w.add(frames(1)[0])
    with pytest.raises(ValueError, match="size changed"):
        w.add(np.zeros((10, 10, 3), np.uint8))
    w.abort()


def test_overwrites_existing_file(tmp_path):
    target = tmp_path / "a.png"
    target.write_bytes(b"old")
    with PngWriter(target) as w:
        w.add(frames(1)[0])
    np.testing.assert_array_equal(np.asarray(Image.open(target)), frames(1)[0])
    umask = os.umask(0o022)
    os.umask(umask)
    assert target.stat().st_mode & 0o777 == 0o666 & ~umask  # not mkstemp's 0600


# ------------------------------------------------------------------ PNG / folder


def test_png_keeps_last(tmp_path):
    fr = frames(3)
    with PngWriter(tmp_path / "a.png") as w:
        for f in fr:
            w.add(f)
    np.testing.assert_array_equal(np.asarray(Image.open(tmp_path / "a.png")), fr[-1])


def test_folder_new(tmp_path):
    fr = frames(3)
    with FolderWriter(tmp_path / "out") as w:
        for f in fr:
            w.add(f)
    assert listing(tmp_path) == ["out"]
    assert listing(tmp_path / "out") == [f"frame_0000{i}.png" for i in range(3)]
    for i, f in enumerate(fr):
        np.testing.assert_array_equal(np.asarray(Image.open(tmp_path / f"out/frame_0000{i}.png")), f)


def test_folder_existing_replaces_only_our_frames(tmp_path):
    d = tmp_path / "out"
    d.mkdir()
    (d / "notes.txt").write_text("keep me")
    for i in range(5):
        (d / f"frame_{i:05d}.png").write_bytes(b"stale")
    with FolderWriter(d) as w:
        for f in frames(2):
            w.add(f)
    assert listing(d) == ["frame_00000.png", "frame_00001.png", "notes.txt"]
    assert listing(tmp_path) == ["out"]


def test_folder_abort(tmp_path):
    w = FolderWriter(tmp_path / "out/")
    w.add(frames(1)[0])
    w.abort()
    assert listing(tmp_path) == []


# ------------------------------------------------------------------ MP4


def mp4_meta(path):
    import imageio_ffmpeg

    gen = imageio_ffmpeg.read_frames(str(path))
    meta = next(gen)
    n = sum(1 for _ in gen)
    return meta, n


@pytest.mark.parametrize("size,expected", [((40, 48), (48, 40)), ((33, 21), (22, 34))])
def test_mp4(tmp_path, size, expected):
    h, w = size
    fr = [f[:h, :w] if f.shape[0] >= h else np.resize(f, (h, w, 3)) for f in frames(7, 40, 48)]
    fr = [np.ascontiguousarray(np.resize(f, (h, w, 3))) for f in fr]
    path = tmp_path / "a.mp4"
    with Mp4Writer(path, fps=30) as writer:
        for f in fr:
            writer.add(f)
    assert writer.padded == (size != (40, 48))
    meta, n = mp4_meta(path)
    assert n == 7
    assert tuple(meta["size"]) == expected
    assert meta["fps"] == pytest.approx(30)
    assert "h264" in meta["codec"]
    assert "yuv420p" in meta.get("pix_fmt", "yuv420p")
    assert listing(tmp_path) == ["a.mp4"]


def test_mp4_leaves_no_pipe_open(tmp_path):
    """ffmpeg's pipes are closed when the file is finished (render shows Python's warnings
    to the user: an unclosed pipe was one, "unclosed file <_io.BufferedReader name=6>")."""
    with warnings.catch_warnings(record=True) as seen:
        warnings.simplefilter("always", ResourceWarning)
        with Mp4Writer(tmp_path / "a.mp4") as writer:
            writer.add(frames(1)[0])
        del writer
        gc.collect()
    assert [str(w.message) for w in seen] == []


def test_mp4_abort(tmp_path):
    w = Mp4Writer(tmp_path / "a.mp4")
    w.add(frames(1)[0])
    w.abort()
    assert listing(tmp_path) == []


# ------------------------------------------------------------------ meshes


def grid_mesh(nw=3, nh=2, z=0.0, name=None):
    i, j = np.mgrid[0:nh, 0:nw]
    pos = np.stack([j.ravel() / (nw - 1), np.full(nw * nh, z), i.ravel() / (nh - 1)], 1)
    tris = []
    for a in range(nh - 1):
        for b in range(nw - 1):
            A, B, C, D = a * nw + b, a * nw + b + 1, (a + 1) * nw + b, (a + 1) * nw + b + 1
            tris += [(A, C, B), (B, C, D)]
    m = SimpleNamespace(positions=pos, normals=np.tile([0.0, 1.0, 0.0], (nw * nh, 1)),
                        uvs=np.stack([j.ravel() / (nw - 1), i.ravel() / (nh - 1)], 1),
                        triangles=np.array(tris))
    if name:
        m.name = name
    return m


def test_obj_groups_roundtrip(tmp_path):
    import trimesh

    meshes = [grid_mesh(4, 3), grid_mesh(2, 2, z=1.5)]
    with ObjWriter(tmp_path / "objs") as w:
        w.add(meshes, ["cloth", "plane_0"])
        w.add(meshes, ["cloth", "plane_0"])
    assert listing(tmp_path / "objs") == ["frame_00000.obj", "frame_00001.obj"]
    text = (tmp_path / "objs/frame_00001.obj").read_text()
    assert text.count("\no ") == 2 and text.count("\nvt ") == 16 and text.count("\nvn ") == 16
    scene = trimesh.load(tmp_path / "objs/frame_00000.obj", force="scene", process=False,
                         split_objects=True)
    geoms = scene.geometry
    assert set(geoms) == {"cloth", "plane_0"}
    np.testing.assert_allclose(geoms["cloth"].vertices, meshes[0].positions)
    np.testing.assert_array_equal(geoms["cloth"].faces, meshes[0].triangles)
    np.testing.assert_allclose(geoms["plane_0"].vertices, meshes[1].positions)
    np.testing.assert_allclose(geoms["cloth"].visual.uv, meshes[0].uvs)
    np.testing.assert_allclose(geoms["cloth"].vertex_normals, meshes[0].normals)


def test_mesh_names():
    from pipeline.scene import Plane, Sphere

    scene = SimpleNamespace(colliders=(Plane((0, 0, 0), (0, 1, 0), 0.5),
                                       Sphere((0, 0, 0), 1.0, 0.1)))
    ms = [grid_mesh()] * 3
    assert outputs.mesh_names(ms, scene) == ["cloth", "sphere_0", "plane_0"]
    assert outputs.mesh_names([grid_mesh(name="a"), grid_mesh(name="b")]) == ["a", "b"]
    assert outputs.mesh_names(ms) == ["cloth", "object_1", "object_2"]


def test_npz(tmp_path):
    path = tmp_path / "p.npz"
    with NpzWriter(path) as w:
        for k in range(3):
            w.add(np.full((6, 3), k, np.float64))
        w.set_meta(times=np.arange(3) / 25.0, faces=np.zeros((4, 3), np.int32))
    data = np.load(path)
    assert data["positions"].shape == (3, 6, 3)
    assert data["positions"][2, 0, 0] == 2
    assert list(data["times"]) == [0, 0.04, 0.08]
    assert listing(tmp_path) == ["p.npz"]


def test_diff_image():
    a = np.zeros((4, 4, 3), np.uint8)
    b = a.copy()
    b[1, 2] = (10, 0, 40)
    d = outputs.diff_image(a, b)
    assert d[1, 2].tolist() == [80, 0, 255] and d.sum() == 335
    assert outputs.diff_image(a, np.zeros((5, 4, 3), np.uint8)).shape == (5, 4, 3)


def test_gif_palette_sample_stays_bounded(tmp_path, monkeypatch):
    monkeypatch.setattr(GifWriter, "SAMPLE_CAP", 3000)
    fr = frames(12)
    with GifWriter(tmp_path / "a.gif") as w:
        for f in fr:
            w.add(f)
            assert w._n_samples <= 3000
    info = gif_info(tmp_path / "a.gif")
    assert info.n == 12
    for got, want in zip(info.frames, fr):
        assert np.abs(got.astype(int) - want).mean() < 6

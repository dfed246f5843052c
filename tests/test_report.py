"""`render report` (pipeline/report.py): HTML + contact sheet comparing shaders and sweeps.

Tiny scenes (8x8 cloth, 10 steps per frame), 64x64 images, durations of 0.2-0.5 s.
The browser test needs Debian's `chromium` package (/usr/bin/chromium); it is skipped
when that is not installed.
"""
from __future__ import annotations

import base64
import functools
import http.server
import io
import json
import math
import os
import re
import shutil
import subprocess
import tempfile
import threading
from html.parser import HTMLParser
from pathlib import Path

import numpy as np
import pytest
from PIL import Image

from pipeline import cli
from pipeline.cli import report, report_runs
from pipeline.cli.report import main
from pipeline.cli.report_plan import build_parser, parse_sweep, plan_report
from pipeline.cli.report_runs import run_simulations

ROOT = Path(__file__).resolve().parents[1]

SMALL = {
    "cloth": {"width": 1, "height": 1, "num_width_points": 8, "num_height_points": 8,
              "thickness": 0.0095, "orientation": 0, "damping": 0.2, "density": 150.0,
              "ks": 5000.0, "enable_structural": True, "enable_shearing": True,
              "enable_bending": True},
    "sphere": {"origin": [0.5, 0.2, 0.5], "radius": 0.2, "friction": 0.3},
    "simulation": {"steps_per_frame": 10},
}


def _all_shaders():
    from shading import SHADERS

    return list(SHADERS)


def _write_scene(folder: Path, data=SMALL) -> Path:
    p = folder / "small.json"
    p.write_text(json.dumps(data))
    return p


# ------------------------------------------------------------------------ HTML parsing


class ReportParser(HTMLParser):
    """Collects the report's figures (attributes, img, caption) and table headers."""

    def __init__(self):
        super().__init__()
        self.figures: list[dict] = []
        self.images: list[dict] = []  # every <img>
        self.grids: list[dict] = []  # {"cols": [...], "rows": [...], "title": str}
        self._fig = None
        self._th = None
        self._cap = None
        self._h2 = None
        self._in_head = False

    def handle_starttag(self, tag, attrs):
        a = dict(attrs)
        if tag == "section" and "data-grid" in a:
            self.grids.append({"cols": [], "rows": [], "title": ""})
        elif tag == "h2" and self.grids:
            self._h2 = []
        elif tag == "thead":
            self._in_head = True
        elif tag == "th" and a.get("scope") in ("col", "row"):
            self._th = (a["scope"], [])
        elif tag == "figure":
            self._fig = {"attrs": a, "img": None, "caption": ""}
        elif tag == "img":
            self.images.append(a)
            if self._fig is not None:
                self._fig["img"] = a
        elif tag == "figcaption":
            self._cap = []

    def handle_data(self, data):
        if self._th is not None:
            self._th[1].append(data)
        if self._cap is not None:
            self._cap.append(data)
        if self._h2 is not None:
            self._h2.append(data)

    def handle_endtag(self, tag):
        if tag == "th" and self._th is not None:
            scope, text = self._th
            self.grids[-1]["cols" if scope == "col" else "rows"].append("".join(text))
            self._th = None
        elif tag == "thead":
            self._in_head = False
        elif tag == "figcaption" and self._fig is not None:
            self._fig["caption"] = "".join(self._cap)
            self._cap = None
        elif tag == "figure" and self._fig is not None:
            self.figures.append(self._fig)
            self._fig = None
        elif tag == "h2" and self._h2 is not None:
            if self.grids:
                self.grids[-1]["title"] = "".join(self._h2)
            self._h2 = None


def parse_report(path: Path) -> ReportParser:
    p = ReportParser()
    p.feed(path.read_text(encoding="utf-8"))
    p.close()
    return p


def decode(src: str) -> np.ndarray:
    m = re.match(r"data:image/(png|gif);base64,(.*)$", src, re.S)
    assert m, src[:60]
    with Image.open(io.BytesIO(base64.b64decode(m.group(2)))) as im:
        return np.asarray(im.convert("RGB"))


# ------------------------------------------------------------------------ the shader report


@pytest.fixture(scope="module")
def shader_report(tmp_path_factory):
    d = tmp_path_factory.mktemp("shaders")
    scene = _write_scene(d)
    out = d / "report.html"
    rc = main([str(scene), "--out", str(out), "--shaders", "all", "--size", "64x64",
               "--duration", "0.2", "--quiet"])
    assert rc == 0
    return d, out


def test_shader_report_one_image_per_shader_and_time(shader_report):
    d, out = shader_report
    shaders = _all_shaders()
    rep = parse_report(out)
    assert len(rep.figures) == len(shaders) * 3
    assert len(rep.images) == len(shaders) * 3  # no other image on the page
    seen = set()
    for fig in rep.figures:
        a = fig["attrs"]
        seen.add((a["data-shader"], a["data-time"]))
        img = decode(fig["img"]["src"])
        assert img.shape == (64, 64, 3)
        assert fig["img"]["width"] == "64" and fig["img"]["height"] == "64"
        # the label names the shader, the time and the render time of that frame
        cap = fig["caption"]
        assert cap.startswith(f"{a['data-shader']} · t = {a['data-time']} s · ")
        assert cap.endswith(f"{a['data-ms']} ms/frame")
        assert float(a["data-ms"]) > 0
        assert "diverged" not in a
    # default times: 0, the middle and the end of --duration; nearest simulator frames (90 fps)
    assert seen == {(s, t) for s in shaders for t in ("0", "0.1", "0.2")}
    frames = {(f["attrs"]["data-time"], f["attrs"]["data-frame"]) for f in rep.figures}
    assert frames == {("0", "0"), ("0.1", "9"), ("0.2", "18")}


def test_shader_report_table_labels(shader_report):
    _, out = shader_report
    rep = parse_report(out)
    assert len(rep.grids) == 1
    g = rep.grids[0]
    assert g["cols"] == _all_shaders()  # shaders side by side
    assert g["rows"] == ["t = 0 s\nframe 0", "t = 0.1 s\nframe 9", "t = 0.2 s\nframe 18"]
    # figures come row by row: row = time, column = shader
    order = [(f["attrs"]["data-time"], f["attrs"]["data-shader"]) for f in rep.figures]
    assert order == [(t, s) for t in ("0", "0.1", "0.2") for s in _all_shaders()]


def test_contact_sheet_size_and_content(shader_report):
    d, out = shader_report
    sheet_path = out.with_suffix(".png")
    assert sheet_path.exists()
    with Image.open(sheet_path) as im:
        sheet = np.asarray(im.convert("RGB"))
    n = len(_all_shaders())
    # W = 72 (row labels) + n * (64 + 6) + 6; H = 24 (title) + 18 (column labels)
    #     + 3 rows * (64 + 14 (caption) + 6) + 6
    assert sheet.shape == (24 + 18 + 3 * (64 + 14 + 6) + 6, 72 + n * (64 + 6) + 6, 3)
    # every cell of the sheet is the HTML's image of the same (time, shader)
    rep = parse_report(out)
    for k, fig in enumerate(rep.figures):
        r, c = divmod(k, n)
        x, y = 72 + c * 70, 24 + 18 + r * 84
        np.testing.assert_array_equal(sheet[y:y + 64, x:x + 64], decode(fig["img"]["src"]))
    # labels were drawn: the label column and header band are not blank
    assert (sheet[42:106, :72] != 255).any()
    assert (sheet[24:42, 72:] != 255).any()


def test_no_temp_files_left(shader_report):
    d, _ = shader_report
    assert sorted(p.name for p in d.iterdir()) == ["report.html", "report.png", "small.json"]


def test_shader_all_is_the_same_as_shaders_all(tmp_path):
    scene = _write_scene(tmp_path)
    args = build_parser().parse_args([str(scene), "--out", str(tmp_path / "x.html"),
                                             "--shader", "all"])
    plan = plan_report(args)
    assert plan.shaders == _all_shaders()
    assert plan.times == [0.0, 1.5, 3.0] and plan.sim_frames == [0, 135, 270]
    args = build_parser().parse_args([str(scene), "--out", str(tmp_path / "x.html"),
                                             "--shader", "toon,phong", "--at", "2,0.5"])
    plan = plan_report(args)
    assert plan.shaders == ["toon", "phong"] and plan.times == [0.5, 2.0]
    assert list(tmp_path.iterdir()) == [scene]


def test_the_warm_up_renders_every_variants_look_before_the_cells_are_timed(tmp_path,
                                                                             monkeypatch):
    # a sweep of render.shadows=false,true: warmed with the first variant alone, the first
    # shadowed cell was timed with the shadow kernels' loading (40.9 against 21.6 ms for a
    # 320x320 tablecloth cell: the sweep read as if shadows cost 1.9x)
    import pipeline.run.frames as frames

    scene = _write_scene(tmp_path)
    args = build_parser().parse_args([str(scene), "--out", str(tmp_path / "x.html"),
                                      "--shader", "toon", "--sweep",
                                      "render.shadows=false,true", "--sweep",
                                      "cloth.ks=500,900"])
    plan = plan_report(args)
    seen = []
    monkeypatch.setattr(frames, "render_frame",
                        lambda scene, *a, shader, **k: seen.append((scene.render.shadows,
                                                                    shader)))
    report.warm_up(plan)
    assert sorted(seen) == [(False, "toon"), (True, "toon")]  # once per look, not per ks


def test_a_cell_is_the_frame_render_draws_at_that_time(tmp_path):
    # a scene with no camera is framed over its whole shot, 0 s to the last time, as
    # `render` frames the animation its flags make; framed over the shown frames alone, a
    # cloth lying on the floor at 1 s and 3 s put the eye at its height (edge on: every
    # cell was empty)

    data = {k: v for k, v in SMALL.items() if k != "sphere"}
    data["plane"] = {"point": [0, 0, 0], "normal": [0, 1, 0], "friction": 0.5}
    scene = _write_scene(tmp_path, data)
    out = tmp_path / "report.html"
    assert main([str(scene), "--out", str(out), "--at", "1,3", "--size", "64x48",
                 "--shader", "phong", "--quiet"]) == 0
    cells = {f["attrs"]["data-time"]: decode(f["img"]["src"])
             for f in parse_report(out).figures}
    # the report's shot: the 25 fps animation of 0-3 s and 3 s itself, which is the
    # animation `render --duration 3.04` makes (76 frames, the last at 3 s)
    for t, duration in (("1", "3.04"), ("3", "3")):
        png = tmp_path / f"{t}.png"
        assert cli.main([str(scene), "--at", t, "--duration", duration, "--size", "64x48",
                         "--out", str(png), "--quiet"]) == 0
        with Image.open(png) as im:
            np.testing.assert_array_equal(cells[t], np.asarray(im.convert("RGB")))


# ------------------------------------------------------------------------ sweeps


def test_one_sweep_grid(tmp_path):
    scene = _write_scene(tmp_path)
    out = tmp_path / "ks.html"
    rc = main([str(scene), "--out", str(out), "--sweep", "cloth.ks=500,5000,50000",
               "--at", "0.1,0.5", "--size", "64x64", "--quiet", "--jobs", "1"])
    assert rc == 0
    rep = parse_report(out)
    assert len(rep.grids) == 1
    g = rep.grids[0]
    assert g["rows"] == ["cloth.ks\n= 500", "cloth.ks\n= 5000", "cloth.ks\n= 50000"]
    assert g["cols"] == ["t = 0.1 s", "t = 0.5 s"]
    assert [(f["attrs"]["data-variant"], f["attrs"]["data-time"], f["attrs"]["data-shader"])
            for f in rep.figures] == [(f"cloth.ks = {k}", t, "phong")
                                      for k in (500, 5000, 50000) for t in ("0.1", "0.5")]
    for f in rep.figures:
        assert f["caption"].startswith(f"{f['attrs']['data-variant']} · phong · t = ")
        assert json.loads(f["attrs"]["data-overrides"]) == [
            "cloth.ks=" + f["attrs"]["data-variant"].split(" = ")[1]]
    # different stiffness, different cloth once it lies on the sphere (free fall is the same)
    imgs = [decode(f["img"]["src"]) for f in rep.figures]
    assert not np.array_equal(imgs[1], imgs[5])
    with Image.open(out.with_suffix(".png")) as im:
        assert im.size == (72 + 2 * 70 + 6, 24 + 18 + 3 * 84 + 6)


def test_two_and_three_sweeps_grid_shapes(tmp_path):
    scene = _write_scene(tmp_path)
    out = tmp_path / "grid.html"
    rc = main([str(scene), "--out", str(out), "--sweep", "cloth.ks=500,5000",
               "--sweep", "cloth.damping=0,0.5,1", "--sweep", "sphere.radius=0.1,0.3",
               "--shader", "normal", "--at", "0.1,0.2", "--size", "64x64", "--quiet"])
    assert rc == 0
    rep = parse_report(out)
    # one grid per value of the third sweep and per time; rows: first sweep; columns: second
    assert len(rep.grids) == 2 * 2
    assert [g["title"] for g in rep.grids] == [
        f"sphere.radius = {r}, t = {t} s, normal" for r in ("0.1", "0.3") for t in ("0.1", "0.2")]
    for g in rep.grids:
        assert g["rows"] == ["cloth.ks\n= 500", "cloth.ks\n= 5000"]
        assert g["cols"] == ["cloth.damping\n= 0", "cloth.damping\n= 0.5", "cloth.damping\n= 1"]
    assert len(rep.figures) == 4 * 2 * 3
    first = rep.figures[:6]
    assert [f["attrs"]["data-variant"] for f in first] == [
        f"cloth.ks = {k}, cloth.damping = {dmp}, sphere.radius = 0.1"
        for k in (500, 5000) for dmp in ("0", "0.5", "1")]
    assert {f["attrs"]["data-shader"] for f in rep.figures} == {"normal"}
    with Image.open(out.with_suffix(".png")) as im:
        # column labels have two lines: header 2 * 12 + 6
        assert im.size == (72 + 3 * 70 + 6, 4 * (24 + 30 + 2 * 84) + 6)


def test_parallel_sweep_equals_serial(tmp_path):
    scene = _write_scene(tmp_path)
    args = build_parser().parse_args(
        [str(scene), "--out", str(tmp_path / "p.html"), "--sweep", "cloth.ks=500,5000,80000",
         "--sweep", "simulation.steps_per_frame=1,10", "--at", "0.1,0.5", "--gif"])
    plan = plan_report(args)
    assert len(plan.variants) == 6
    serial = run_simulations(plan, jobs=1)
    parallel = run_simulations(plan, jobs=max(2, os.cpu_count() or 1))
    assert any(r.error for r in serial)  # ks=80000 with one step per frame blows up
    for s, p in zip(serial, parallel):
        assert s.error == p.error
        assert s.warnings == p.warnings
        assert sorted(s.positions) == sorted(p.positions)
        for j in s.positions:
            np.testing.assert_array_equal(s.positions[j], p.positions[j])
    assert list(tmp_path.iterdir()) == [scene]


def test_diverging_variant_is_a_labelled_cell(tmp_path, capsys):
    scene = _write_scene(tmp_path)
    out = tmp_path / "div.html"
    rc = main([str(scene), "--out", str(out), "--set", "cloth.ks=80000",
               "--sweep", "simulation.steps_per_frame=1,10", "--at", "0,0.5", "--size", "64x64",
               "--gif", "--gif-size", "32x32"])
    assert rc == 0
    err = capsys.readouterr().err
    assert "render: warning: simulation.steps_per_frame = 1: simulation diverged at frame" in err
    rep = parse_report(out)
    cells = {(f["attrs"]["data-variant"], f["attrs"]["data-time"]): f for f in rep.figures}
    assert len(cells) == 4
    bad = cells[("simulation.steps_per_frame = 1", "0.5")]
    assert bad["attrs"]["data-diverged"] == "1" and "diverged" in bad["attrs"]["class"]
    assert "diverged: simulation diverged at frame" in bad["caption"]
    assert "kinetic energy" in bad["caption"] or "non-finite" in bad["caption"]  # in <details>
    assert decode(bad["img"]["src"]).shape == (64, 64, 3)  # a placeholder image, labelled
    for key in (("simulation.steps_per_frame = 1", "0"), ("simulation.steps_per_frame = 10", "0"),
                ("simulation.steps_per_frame = 10", "0.5")):
        assert "data-diverged" not in cells[key]["attrs"]
    # the GIF grid: 0.5 s at 10 fps, one column, two rows, no captions
    with Image.open(out.with_suffix(".gif")) as gif:
        assert gif.n_frames == 5
        # row labels wider than 72 px widen the label column to the text width + 2 * 6
        from PIL import ImageDraw, ImageFont

        d = ImageDraw.Draw(Image.new("RGB", (1, 1)))
        label_w = math.ceil(d.textlength("simulation.steps_per_frame",
                                         font=ImageFont.load_default())) + 12
        assert label_w > 72
        assert gif.size == (label_w + 32 + 6 + 6, 24 + 18 + 2 * (32 + 6) + 6)
    assert sum(1 for im in rep.images if im["src"].startswith("data:image/gif;base64,")) == 1


def test_sweep_values_with_commas_inside_lists():
    s = parse_sweep('sphere.0.origin=[0.5,0.2,0.5], [0.5,0.1,0.5],"a,b"')
    assert s.key == "sphere.0.origin"
    assert s.values == ("[0.5,0.2,0.5]", "[0.5,0.1,0.5]", '"a,b"')


# ------------------------------------------------------------------------ bad input


BAD = [
    (["--sweep", "cloth.ks"], "expected --sweep dotted.key=V1,V2"),
    (["--sweep", "=1,2"], "expected --sweep dotted.key=V1,V2"),
    (["--sweep", "cloth..ks=1,2"], "expected --sweep dotted.key=V1,V2"),
    (["--sweep", "cloth.ks=1,,2"], "empty value"),
    (["--sweep", "cloth.ks="], "empty value"),
    (["--sweep", "cloth.ks=1,1"], "given twice"),
    (["--sweep", "cloth.ks=1,2", "--sweep", "cloth.ks=3,4"], "swept twice"),
    (["--sweep", "cloth.kss=1,2"], "kss"),
    (["--sweep", "cloth.ks=500,-1"], "cloth.ks"),
    (["--sweep", "cloth.ks=500,\"soft\""], "cloth.ks"),
    (["--set", "cloth.nope=1"], "nope"),
    (["--shaders", "phong,shiny"], "unknown shader 'shiny'"),
    (["--shaders", "all,phong"], "'all' cannot be combined"),
    (["--shader", "shiny", "--sweep", "cloth.ks=1,2"], "unknown shader 'shiny'"),
    (["--shaders", "phong", "--sweep", "cloth.ks=1,2"], "uses one shader"),
    (["--shader", "phong,toon", "--sweep", "cloth.ks=1,2"], "uses one shader"),
    (["--at", "-1"], "expected times >= 0"),
    (["--at", "1,x"], "expected times in seconds"),
    (["--at", "1,1"], "given twice"),
    (["--at", "nan"], "expected times >= 0"),
    (["--at", "2", "--duration", "1"], "beyond --duration"),
    (["--size", "64"], "WIDTHxHEIGHT"),
    (["--duration", "0"], "positive"),
    (["--gif-fps", "60", "--gif"], "too high"),
    (["--gif-size", "32x32"], "need --gif"),
    (["--bogus"], "unrecognized"),
]


@pytest.mark.parametrize("extra,expected", BAD, ids=[" ".join(b[0]) for b in BAD])
def test_bad_input_exits_2_before_any_work(tmp_path, capsys, monkeypatch, extra, expected):
    scene = _write_scene(tmp_path)

    def no_work(*a, **k):
        raise AssertionError("work started on bad input")

    monkeypatch.setattr(report, "build_report", no_work)
    monkeypatch.setattr(report_runs, "simulate_variant", no_work)
    rc = main([str(scene), "--out", str(tmp_path / "r.html")] + extra)
    err = capsys.readouterr().err
    assert rc == 2, err
    assert err.startswith("render")
    assert expected in err
    assert "Traceback" not in err
    assert list(tmp_path.iterdir()) == [scene]  # nothing written, no temp file left


@pytest.mark.parametrize("out,expected", [("r.png", "ending in .html"),
                                          ("nodir/r.html", "does not exist")])
def test_bad_output_path(tmp_path, capsys, out, expected):
    scene = _write_scene(tmp_path)
    rc = main([str(scene), "--out", str(tmp_path / out)])
    assert rc == 2
    assert expected in capsys.readouterr().err
    assert list(tmp_path.iterdir()) == [scene]


def test_bad_scene_file(tmp_path, capsys):
    rc = main([str(tmp_path / "missing.json"), "--out", str(tmp_path / "r.html")])
    assert rc == 2
    assert "missing.json" in capsys.readouterr().err
    assert list(tmp_path.iterdir()) == []


def test_failure_midway_leaves_nothing(tmp_path, capsys, monkeypatch):
    scene = _write_scene(tmp_path)

    def boom(*a, **k):
        raise RuntimeError("kaboom")

    monkeypatch.setattr(report, "build_grids", boom)
    rc = main([str(scene), "--out", str(tmp_path / "r.html"), "--shaders", "phong",
               "--duration", "0.05", "--size", "16x16"])
    assert rc == 1
    assert "internal error: RuntimeError: kaboom" in capsys.readouterr().err
    assert list(tmp_path.iterdir()) == [scene]


def test_help():
    assert main(["--help"]) == 0


# ------------------------------------------------------------------------ in a browser

CHROMIUM = shutil.which("chromium") or (
    "/usr/bin/chromium" if os.path.exists("/usr/bin/chromium") else None)

HARNESS = """<!DOCTYPE html><html><body><pre id="result">pending</pre>
<iframe id="f" src="{page}" width="1400" height="900"></iframe>
<script>
window.addEventListener('load', function () {{
  var imgs = Array.from(document.getElementById('f').contentDocument.images);
  document.getElementById('result').textContent = JSON.stringify(imgs.map(function (im) {{
    return {{src: im.src.slice(0, 22), complete: im.complete, w: im.naturalWidth,
             h: im.naturalHeight}};
  }}));
}});
</script></body></html>
"""


class _QuietHandler(http.server.SimpleHTTPRequestHandler):
    def log_message(self, *args):
        pass


def _chromium(args, timeout=120):
    with tempfile.TemporaryDirectory() as profile:
        cmd = [CHROMIUM, "--headless", "--no-sandbox", "--disable-gpu", "--disable-quic",
               "--no-first-run", "--disable-background-networking",
               "--disable-component-update", "--disable-sync",
               f"--user-data-dir={profile}"] + args
        return subprocess.run(cmd, capture_output=True, text=True, timeout=timeout)


@pytest.mark.skipif(CHROMIUM is None, reason="chromium is not installed "
                    "(apt-get install -y chromium gives /usr/bin/chromium)")
def test_report_loads_in_a_real_browser(tmp_path):
    scene = _write_scene(tmp_path)
    out = tmp_path / "report.html"
    rc = main([str(scene), "--out", str(out), "--shaders", "phong,normal,toon",
               "--duration", "0.2", "--size", "64x64", "--gif", "--gif-size", "32x32",
               "--quiet"])
    assert rc == 0
    (tmp_path / "harness.html").write_text(HARNESS.format(page=out.name))
    server = http.server.ThreadingHTTPServer(
        ("127.0.0.1", 0), functools.partial(_QuietHandler, directory=str(tmp_path)))
    thread = threading.Thread(target=server.serve_forever, daemon=True)
    thread.start()
    try:
        base = f"http://127.0.0.1:{server.server_address[1]}"
        res = _chromium(["--virtual-time-budget=10000", "--dump-dom", f"{base}/harness.html"])
        m = re.search(r'<pre id="result">(.*?)</pre>', res.stdout, re.S)
        assert m, f"no result from chromium: {res.stdout[-500:]} {res.stderr[-1500:]}"
        images = json.loads(m.group(1).replace("&quot;", '"').replace("&amp;", "&"))
        shot = tmp_path / "screenshot.png"
        _chromium(["--window-size=1000,900", f"--screenshot={shot}", f"{base}/{out.name}"])
    finally:
        server.shutdown()
        server.server_close()
    # 3 shaders x 3 times, plus the animated grid
    assert len(images) == 3 * 3 + 1
    for im in images:
        assert im["complete"] and im["w"] > 0 and im["h"] > 0, im
    assert sum(im["src"].startswith("data:image/gif") for im in images) == 1
    assert {(im["w"], im["h"]) for im in images if im["src"].startswith("data:image/png")} \
        == {(64, 64)}
    with Image.open(shot) as s:  # the page was drawn: not a blank screenshot
        a = np.asarray(s.convert("RGB"))
    assert a.shape[:2] == (900, 1000)
    assert len(np.unique(a.reshape(-1, 3), axis=0)) > 50


def test_variants_drawn_differently_share_one_simulation():
    from pipeline.cli.report_plan import Variant

    vs = [Variant(i, (), ov, "") for i, ov in enumerate([
        ("render.shadows=false", "cloth.ks=500"), ("render.shadows=true", "cloth.ks=500"),
        ("render.shadows=false", "cloth.ks=900"), ("light.radius=0.1", "cloth.ks=900")])]
    chosen, of = report_runs.shared_simulations(vs)
    assert [v.overrides for v in chosen] == [vs[0].overrides, vs[2].overrides]
    assert [v.index for v in chosen] == [0, 1] and of == [0, 0, 1, 1]
    # a camera changes the framing: not shared
    chosen, of = report_runs.shared_simulations(
        [Variant(0, (), ("camera.vfov=30",), ""), Variant(1, (), ("camera.vfov=40",), "")])
    assert of == [0, 1]

"""Dask distributed (docs/distributed.md): `render batch`, `render report --sweep` and one
long `render` on a real distributed.LocalCluster of 2 worker processes on 127.0.0.1.

Every result is compared with the one-process run, computed here with the plain command
(no cluster). One module-scoped cluster serves the in-process tests (`--scheduler ADDR`);
the signal test starts its own (`--workers 2`) in a `render` process. Tiny scenes: a
10x10 cloth, 48x48 images, half a second of animation.
"""
from __future__ import annotations

import json
import logging
import os
import re
import signal
import socket
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
from conftest import child_env, cloth_dict, process_alive, scene_dict
from distributed import Client, LocalCluster

from pipeline.cli import batch, main, report

SCENE = scene_dict(cloth_dict(10, 10, thickness=0.0095, damping=0.2, density=150.0, ks=5000.0),
                   steps_per_frame=10, spheres=[((0.5, 0.2, 0.5), 0.2, 0.3)])
SMALL = ["--size", "48x48", "--duration", "0.5", "--quiet"]

pytestmark = pytest.mark.skipif(not os.path.isdir("/proc/self"), reason="needs /proc")


@pytest.fixture(scope="module")
def dask(tmp_path_factory):
    """(scheduler address, client) of 2 worker processes, one thread each, on loopback."""
    with LocalCluster(n_workers=2, threads_per_worker=1, processes=True, host="127.0.0.1",
                      dashboard_address=None, silence_logs=logging.ERROR) as cluster, \
            Client(cluster, set_as_default=False) as client:
        yield cluster.scheduler_address, client


def write_scene(folder: Path, name: str = "s", **changes) -> Path:
    data = json.loads(json.dumps(SCENE))
    for key, value in changes.items():
        block, _, item = key.partition("__")
        data[block][item] = value
    path = folder / f"{name}.json"
    path.write_text(json.dumps(data))
    return path


def files(folder: Path) -> dict[str, bytes]:
    return {p.name: p.read_bytes() for p in sorted(folder.iterdir())}


def render_cmd() -> list[str]:
    return [sys.executable, "-c", "import sys; from pipeline.cli import main; sys.exit(main())"]


# --------------------------------------------------------------------------- one long render


def test_long_render_frames_are_those_of_one_process(dask, tmp_path):
    scene = write_scene(tmp_path)
    assert main([str(scene), "--out", f"{tmp_path}/one/"] + SMALL) == 0
    assert main([str(scene), "--out", f"{tmp_path}/many/", "--scheduler", dask[0]]
                + SMALL) == 0
    one, many = files(tmp_path / "one"), files(tmp_path / "many")
    assert len(one) == 12 and one == many  # every PNG byte for byte
    assert sorted(p.name for p in tmp_path.iterdir()) == ["many", "one", "s.json"]


def test_long_render_gif_and_a_diverging_simulation(dask, tmp_path, capsys):
    scene = write_scene(tmp_path)
    assert main([str(scene), "--out", str(tmp_path / "one.gif")] + SMALL) == 0
    assert main([str(scene), "--out", str(tmp_path / "many.gif"), "--scheduler", dask[0]]
                + SMALL) == 0
    assert (tmp_path / "one.gif").read_bytes() == (tmp_path / "many.gif").read_bytes()
    capsys.readouterr()
    bad = write_scene(tmp_path, "bad", cloth__ks=1e9, simulation__steps_per_frame=1)
    rc = main([str(bad), "--out", str(tmp_path / "bad.gif"), "--scheduler", dask[0]] + SMALL)
    err = capsys.readouterr().err
    assert rc == 1, err
    assert "render: simulation diverged at frame" in err and "Traceback" not in err
    assert not list(tmp_path.glob("bad.gif*")) and not list(tmp_path.glob(".bad.gif*"))


def test_killed_worker_mid_render_output_complete_and_identical(dask, tmp_path):
    """kill -9 the worker running the simulation once the first frames are written."""
    address, client = dask
    scene = write_scene(tmp_path, simulation__steps_per_frame=1500)
    # the course camera: the client does not simulate the shot ahead to frame it first
    flags = ["--size", "32x32", "--duration", "1.2", "--quiet", "--set", "camera=course"]
    proc = subprocess.Popen(render_cmd() + [str(scene), "--out", f"{tmp_path}/many/",
                                            "--scheduler", address] + flags,
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                            env=child_env())
    victim = None
    deadline = time.monotonic() + 300
    while victim is None:
        assert proc.poll() is None, proc.communicate()
        assert time.monotonic() < deadline, "the render never got going"
        if list(tmp_path.glob(".many.*.part/frame_00000.png")):  # frames being written
            busy = {w: ks for w, ks in client.processing().items()
                    if any(str(k).endswith("-simulate") for k in ks)}
            if busy:
                victim = client.run(os.getpid, workers=list(busy))[next(iter(busy))]
        time.sleep(0.05)
    os.kill(victim, signal.SIGKILL)
    out, err = proc.communicate(timeout=600)
    assert proc.returncode == 0, err
    assert main([str(scene), "--out", f"{tmp_path}/one/"] + flags) == 0
    one, many = files(tmp_path / "one"), files(tmp_path / "many")
    assert len(one) == 30 and one == many
    client.wait_for_workers(2, timeout=120)  # the nanny restarted it, for the next tests


# --------------------------------------------------------------------------- batch


def test_batch_outputs_equal_one_process_renders_and_failures_are_rows(dask, tmp_path, capsys):
    scenes = tmp_path / "scenes"
    scenes.mkdir()
    write_scene(scenes, "a")
    # b: robust self-contact, bit for bit the same on a worker as in this process
    write_scene(scenes, "b", cloth__ks=500.0, cloth__damping=0.5, simulation__contact="robust",
                simulation__self_collision=True)
    write_scene(scenes, "diverges", cloth__ks=1e9, simulation__steps_per_frame=1)
    (scenes / "broken.json").write_text('{"cloth": 3}')
    out = tmp_path / "out"
    rc = batch.main([str(scenes), str(tmp_path / "missing.json"), "--out-dir", str(out),
                     "--scheduler", dask[0], "--size", "48x48", "--duration", "0.5", "-q"])
    table = capsys.readouterr().out
    assert rc == 1
    rows = {line.split()[0]: line for line in table.splitlines()[1:-1]}
    assert set(rows) == {str(scenes / f"{n}.json") for n in ("a", "b", "broken", "diverges")
                         } | {str(tmp_path / "missing.json")}
    assert re.search(r"\s12\s+[\d.]+\s+[\d.]+ KB\s+ok$", rows[str(scenes / "a.json")])
    assert "bad input: " in rows[str(scenes / "broken.json")] and "cloth" in rows[
        str(scenes / "broken.json")]
    assert "failed: simulation diverged at frame" in rows[str(scenes / "diverges.json")]
    assert "cannot read" in rows[str(tmp_path / "missing.json")]
    assert table.splitlines()[-1].startswith("5 scenes: 2 ok, 3 failed;")
    assert sorted(os.listdir(out)) == ["a.gif", "b.gif"]  # nothing else, nothing partial
    for name in ("a", "b"):
        ref = tmp_path / f"ref_{name}.gif"
        assert main([str(scenes / f"{name}.json"), "--out", str(ref), "--size", "48x48",
                     "--duration", "0.5", "-q"]) == 0
        assert (out / f"{name}.gif").read_bytes() == ref.read_bytes()
    # every worker took the numba cache lock (the plugin)
    assert set(dask[1].run(lambda: __import__("clothjit.compile_lock").compile_lock._installed
                           ).values()) == {True}


def test_batch_png_format_without_cluster(tmp_path, capsys):
    scene = write_scene(tmp_path, "a")
    rc = batch.main([str(scene), "--out-dir", str(tmp_path / "out"), "--format", "png",
                     "--size", "48x48", "--duration", "0.5"])
    assert rc == 0, capsys.readouterr().err
    assert "1 scene: 1 ok, 0 failed" in capsys.readouterr().out
    assert main([str(scene), "--out", str(tmp_path / "ref.png"), "--size", "48x48",
                 "--duration", "0.5", "-q"]) == 0
    assert (tmp_path / "out" / "a.png").read_bytes() == (tmp_path / "ref.png").read_bytes()


@pytest.mark.parametrize("extra,expected", [
    (["--out-dir", "{t}/nodir/out"], "does not exist"),
    (["--out-dir", "{t}/a.json"], "a file of that name exists"),
    (["--out-dir", "{t}/o", "--fps", "60"], "too high for a GIF"),
    (["--out-dir", "{t}/o", "--shader", "shiny"], "unknown shader 'shiny'"),
    (["--out-dir", "{t}/o", "--workers", "0"], "expected a whole number >= 1"),
    (["--out-dir", "{t}/o", "--scheduler", "not an address"], "expected tcp://HOST:PORT"),
    (["--out-dir", "{t}/o", "--workers", "2", "--scheduler", "tcp://127.0.0.1:1"],
     "not allowed with"),
    (["{t}/sub/a.json", "--out-dir", "{t}/o"], "would both write"),
    ([], "required: --out-dir"),
])
def test_batch_bad_command_line_exits_2_before_any_work(tmp_path, capsys, extra, expected):
    write_scene(tmp_path, "a")
    (tmp_path / "sub").mkdir()
    write_scene(tmp_path / "sub", "a")
    before = sorted(tmp_path.rglob("*"))
    rc = batch.main([str(tmp_path / "a.json")] + [e.format(t=tmp_path) for e in extra])
    err = capsys.readouterr().err
    assert rc == 2 and expected in err and "Traceback" not in err, err
    assert sorted(tmp_path.rglob("*")) == before


# --------------------------------------------------------------------------- report


def test_report_sweep_on_dask_is_the_serial_report(dask, tmp_path):
    scene = write_scene(tmp_path)
    flags = ["--sweep", "cloth.ks=500,5000", "--at", "0.2,0.4", "--size", "48x48", "--gif",
             "--gif-size", "32x32", "--quiet"]
    assert report.main([str(scene), "--out", str(tmp_path / "one.html"), "--jobs", "1"]
                       + flags) == 0
    assert report.main([str(scene), "--out", str(tmp_path / "many.html"),
                        "--scheduler", dask[0]] + flags) == 0
    assert (tmp_path / "one.gif").read_bytes() == (tmp_path / "many.gif").read_bytes()

    def measured_out(name):  # times, the date and where it ran are measured, not rendered
        text = re.sub(r"\b(one|many)\.(png|gif)\b", r"R.\2", (tmp_path / name).read_text())
        text = re.sub(r'[\d.]+ ms|data-ms="[\d.]+"', "T", text)
        return re.sub(r"<dt>(processes|generated|simulation[^<]*)</dt><dd>[^<]*</dd>", "", text)

    one, many = measured_out("one.html"), measured_out("many.html")
    assert one == many
    assert len(re.findall(r'src="data:image/png;base64,', one)) == 4
    assert "2 Dask workers" in (tmp_path / "many.html").read_text()
    # the contact sheets: every cell (and label) the same; only the render-time captions
    # under the cells (rows y+48 .. y+62) may differ
    from PIL import Image

    a, b = (np.asarray(Image.open(tmp_path / f"{n}.png").convert("RGB")) for n in ("one", "many"))
    differs = np.flatnonzero((a != b).any(axis=(1, 2)))
    caption_rows = {y + 48 + d for y in (24 + 18, 24 + 18 + 68) for d in range(14)}
    assert set(differs.tolist()) <= caption_rows


def test_report_jobs_and_workers_together_is_a_bad_command_line(tmp_path, capsys):
    scene = write_scene(tmp_path)
    rc = report.main([str(scene), "--out", str(tmp_path / "r.html"), "--sweep",
                      "cloth.ks=1,2", "--jobs", "2", "--workers", "2"])
    assert rc == 2 and "not both" in capsys.readouterr().err
    assert sorted(os.listdir(tmp_path)) == ["s.json"]


# --------------------------------------------------------------------------- a mesh cloth


def test_mesh_cloth_batch_report_and_long_render_on_dask(dask, tmp_path, capsys):
    """A mesh cloth (cloth.mesh, named relative to its scene's folder: the workers load
    it from the scene's shipped folder) on the cluster: batch outputs, the sweep report's
    GIF grid and a long render's GIF, each byte for byte the one-process run's."""
    from test_mesh_cli import write_mesh_scene

    folder = tmp_path / "scenes"
    folder.mkdir()
    a = write_mesh_scene(folder, "a")
    write_mesh_scene(folder, "b", simulation__model="fem")
    small = ["--size", "32x32", "--duration", "0.2", "-q"]
    assert batch.main([str(folder), "--out-dir", str(tmp_path / "out"), "--scheduler",
                       dask[0]] + small) == 0, capsys.readouterr()
    for name in ("a", "b"):
        ref = tmp_path / f"ref_{name}.gif"
        assert main([str(folder / f"{name}.json"), "--out", str(ref)] + small) == 0
        assert (tmp_path / "out" / f"{name}.gif").read_bytes() == ref.read_bytes()
    flags = ["--sweep", "cloth.ks=200,2000", "--at", "0.2", "--size", "32x32", "--gif",
             "--gif-size", "24x24", "--quiet"]
    assert report.main([str(a), "--out", str(tmp_path / "one.html"), "--jobs", "1"]
                       + flags) == 0
    assert report.main([str(a), "--out", str(tmp_path / "many.html"), "--scheduler",
                        dask[0]] + flags) == 0
    assert (tmp_path / "one.gif").read_bytes() == (tmp_path / "many.gif").read_bytes()
    assert main([str(a), "--out", str(tmp_path / "many_a.gif"), "--scheduler", dask[0]]
                + small) == 0
    assert (tmp_path / "many_a.gif").read_bytes() == (tmp_path / "ref_a.gif").read_bytes()


def test_mesh_cloth_on_two_local_workers_draws_the_frames_of_one_process(tmp_path):
    """`--workers 2`: a LocalCluster of its own; every PNG byte for byte."""
    from test_mesh_cli import write_mesh_scene

    scene = write_mesh_scene(tmp_path, simulation__model="fem")
    small = ["--size", "32x32", "--duration", "0.3", "-q"]
    assert main([str(scene), "--out", f"{tmp_path}/one/"] + small) == 0
    assert main([str(scene), "--out", f"{tmp_path}/many/", "--workers", "2"] + small) == 0
    one, many = files(tmp_path / "one"), files(tmp_path / "many")
    assert len(one) == 8 and one == many


# --------------------------------------------------------------------------- faults


def test_scheduler_that_does_not_answer_exits_2_within_10_s(tmp_path, capsys):
    scene = write_scene(tmp_path)
    silent = socket.socket()  # accepts connections (the kernel does), never answers
    silent.bind(("127.0.0.1", 0))
    silent.listen(8)
    address = f"tcp://127.0.0.1:{silent.getsockname()[1]}"
    try:
        for run in (lambda: main([str(scene), "--out", str(tmp_path / "x.gif"),
                                  "--scheduler", address] + SMALL),
                    lambda: batch.main([str(scene), "--out-dir", str(tmp_path / "o"),
                                        "--scheduler", address])):
            t0 = time.monotonic()
            rc = run()
            took = time.monotonic() - t0
            err = capsys.readouterr().err
            assert rc == 2 and took < 10, (rc, took, err)
            assert f"--scheduler {address}: no Dask scheduler answered within" in err
            assert "Traceback" not in err and "try 'render --help'" not in err
    finally:
        silent.close()
    assert sorted(os.listdir(tmp_path)) == ["s.json"]


def descendants(pid: int) -> set[int]:
    """Every live process below `pid` (from /proc)."""
    parents = {}
    for entry in Path("/proc").iterdir():
        if entry.name.isdigit():
            try:
                stat = (entry / "stat").read_text()
            except OSError:
                continue
            fields = stat[stat.rindex(")") + 2:].split()
            if fields[0] != "Z":
                parents[int(entry.name)] = int(fields[1])
    found, todo = set(), [pid]
    while todo:
        p = todo.pop()
        kids = {c for c, parent in parents.items() if parent == p}
        todo += list(kids - found)
        found |= kids
    return found


def test_sigterm_cancels_the_local_cluster_and_leaves_nothing(tmp_path):
    # the course camera: no framing pass in the client (40 s of simulating ahead here)
    # before the render tasks start writing frames
    scene = write_scene(tmp_path, simulation__steps_per_frame=3000)
    proc = subprocess.Popen(render_cmd() + [str(scene), "--out", f"{tmp_path}/frames/",
                                            "--workers", "2", "--size", "32x32",
                                            "--duration", "2", "--set", "camera=course"],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                            env=child_env())
    deadline = time.monotonic() + 300
    while not list(tmp_path.glob(".frames.*.part/frame_00000.png")):
        assert proc.poll() is None, proc.communicate()
        assert time.monotonic() < deadline, "the render never got going"
        time.sleep(0.05)
    kids = descendants(proc.pid)
    assert len(kids) >= 2  # the worker processes
    os.kill(proc.pid, signal.SIGTERM)
    _, err = proc.communicate(timeout=120)
    assert proc.returncode == 143, err
    assert "render: interrupted (SIGTERM); no output written" in err
    assert sorted(os.listdir(tmp_path)) == ["s.json"]
    end = time.monotonic() + 30
    while any(process_alive(k) for k in kids) and time.monotonic() < end:
        time.sleep(0.1)
    assert not [k for k in kids if process_alive(k)]


def test_without_cluster_flags_distributed_is_never_imported(tmp_path):
    scene = write_scene(tmp_path)
    code = ("import sys; from pipeline.cli import main; from pipeline.cli import batch; "
            f"assert main([{str(scene)!r}, '--out', {str(tmp_path / 'x.gif')!r}, '-q', "
            "'--size', '16x16', '--duration', '0.1']) == 0; "
            f"assert batch.main([{str(scene)!r}, '--out-dir', {str(tmp_path / 'o')!r}, "
            "'--size', '16x16', '--duration', '0.1']) == 0; "
            "assert 'distributed' not in sys.modules and 'dask' not in sys.modules, "
            "sorted(m for m in sys.modules if 'dask' in m or 'distrib' in m)")
    r = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                       env=child_env(), timeout=600)
    assert r.returncode == 0, r.stderr
    assert (tmp_path / "o" / "s.gif").read_bytes() == (tmp_path / "x.gif").read_bytes()


def test_compiling_waits_for_another_process_holding_the_cache_lock(tmp_path):
    """While another process compiles (holds the lock exclusively), this one's compile
    waits; it goes on once the lock is released."""
    import threading

    import numba

    from clothjit import compile_lock

    compile_lock.install()
    numba.njit(lambda x: x + 1)(1)  # numba's compiler warmed up: a compile takes < 1.5 s
    holder = subprocess.Popen(
        [sys.executable, "-c", "import fcntl, os, sys; "
         f"fd = os.open({compile_lock.lock_path()!r}, os.O_RDWR | os.O_CREAT); "
         "fcntl.flock(fd, fcntl.LOCK_EX); print('held', flush=True); sys.stdin.read()"],
        stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True, env=child_env())
    try:
        assert holder.stdout.readline().strip() == "held"
        done = threading.Event()

        def compile_something():
            numba.njit(lambda x: x * 3 + 1)(2)  # a new function: numba compiles it
            done.set()

        thread = threading.Thread(target=compile_something, daemon=True)
        thread.start()
        assert not done.wait(1.5)  # blocked behind the other process
    finally:
        holder.stdin.close()  # the holder exits: the kernel releases its lock
        holder.wait(timeout=30)
    assert done.wait(60)

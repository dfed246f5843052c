"""Render benchmark: frames per second per shader, per-stage times, start-up.

    python benchmarks/render.py [--quick] [--shaders phong,normal] [--stages] [--startup]
                                [--cold] [--scaling] [--looks]

Scenes: the sphere scene (50x50 cloth + sphere, frame 0 positions) and a 200x200 waved
cloth, at 800x800 and 1920x1080. Compile time (first call) is reported apart; warm
numbers are wall-clock times of renders into a reused Renderer (the finished uint8 image
included; no per-frame allocation of image buffers) plus the cloth mesh rebuild, as the
best and the median of the repetitions (the best is the machine's capability, the median
what a loaded machine gives: the load average is printed).

--stages    best-of time of each stage (mesh = cloth normals/tangents, prepare = params
            and textures, gather = vertex attributes, geometry = projection + triangle
            setup + binning, raster, shade) per scene and size.
--startup   per shader, a new process with a warm cache: import time and time to the
            first rendered frame (256x256 sphere scene); --cold also compiles from
            scratch (into a temporary NUMBA_CACHE_DIR, the real cache is not touched).
--scaling   time ratio for 4x the pixels (800x800 -> 1600x1600) per scene.
--looks     per scene (with a floor plane under it to receive shadows) and size: the
            shader plain, with shadows, with ambient occlusion and with both, measured
            in alternating rounds; the best time of each and its ratio to plain.
--cpu       frame times in this thread's CPU time: with NUMBA_NUM_THREADS=1 all the work,
            without the waits other processes on the machine cause (2x swings).
Threads: NUMBA_NUM_THREADS (default: all cores); compare NUMBA_NUM_THREADS=1 and 2.
"""
from __future__ import annotations

import argparse
import os
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

import numba  # noqa: E402

import shading  # noqa: E402

STAGES = ("mesh", "prepare", "gather", "geometry", "raster", "shade")
clock = time.perf_counter  # --cpu: time.thread_time


def grid(nw, nh, width=1.0, height=1.0):
    j = np.tile(np.arange(nw, dtype=np.float64), nh)
    i = np.repeat(np.arange(nh, dtype=np.float64), nw)
    return np.stack([width * j / (nw - 1), np.ones(nw * nh), height * i / (nh - 1)], axis=1)


def scenes():
    pos = grid(50, 50)
    sph = shading.sphere_mesh((0.5, 0.2, 0.5), 0.2)
    yield "sphere 50x50", pos, 50, 50, [sph]
    pos2 = grid(200, 200)
    # a gently waved 200x200 cloth so it is seen at an angle
    pos2[:, 1] += 0.05 * np.sin(pos2[:, 0] * 12) * np.cos(pos2[:, 2] * 9)
    yield "cloth 200x200", pos2, 200, 200, []


def bench(shader, pos, nw, nh, extra, w, h, reps, params=None):
    """(first call s, best s, median s, best render-only s, best per stage s)."""
    cam = shading.Camera.default_for_cloth(pos, 1.0, 1.0, width=w, height=h)
    r = shading.Renderer(w, h)
    t0 = clock()
    r.render([shading.cloth_mesh(pos, nw, nh)] + extra, cam, None, shader, params)
    first = clock() - t0
    for _ in range(3):
        r.render([shading.cloth_mesh(pos, nw, nh)] + extra, cam, None, shader, params)
    times, rtimes = [], []
    stages = dict.fromkeys(STAGES, float("inf"))
    st = {}
    for _ in range(reps):
        t0 = clock()
        meshes = [shading.cloth_mesh(pos, nw, nh)] + extra
        t1 = clock()
        r.render(meshes, cam, None, shader, params, timings=st)
        t2 = clock()
        times.append(t2 - t0)
        rtimes.append(t2 - t1)
        st["mesh"] = t1 - t0
        for k in STAGES:
            stages[k] = min(stages[k], st[k])
    return first, min(times), statistics.median(times), min(rtimes), stages


LOOKS = (("plain", {}), ("shadows", {"shadows": True}),
         ("occlusion", {"ambient_occlusion": True}),
         ("both", {"shadows": True, "ambient_occlusion": True}))


def looks(shaders, sizes, reps, rounds=3):
    """Each look's best frame time over alternating rounds, and its ratio to plain."""
    floor = shading.plane_mesh((0.5, 0.0, 0.5), (0.0, 1.0, 0.0))
    print(f"{'scene':<14} {'size':>9} {'shader':<9}"
          + "".join(f" {name + ' ms':>13}" for name, _ in LOOKS)
          + "".join(f" {name + ' x':>11}" for name, _ in LOOKS[1:]))
    for name, pos, nw, nh, extra in scenes():
        for w, h in sizes:
            for sh in shaders:
                best = {k: float("inf") for k, _ in LOOKS}
                for _ in range(rounds):
                    for k, prm in LOOKS:
                        best[k] = min(best[k], bench(sh, pos, nw, nh, extra + [floor], w, h,
                                                     reps, prm)[1])
                print(f"{name:<14} {w}x{h:<5} {sh:<9}"
                      + "".join(f" {best[k] * 1e3:13.2f}" for k, _ in LOOKS)
                      + "".join(f" {best[k] / best['plain']:11.2f}" for k, _ in LOOKS[1:]),
                      flush=True)


def load():
    try:
        return "load average %.2f %.2f %.2f" % os.getloadavg()
    except OSError:
        return "load average unknown"


def header():
    print(f"# {numba.get_num_threads()} thread(s) (NUMBA_NUM_THREADS), {os.cpu_count()} cpu(s), "
          f"{load()}")


STARTUP = r"""
import time, sys
t0 = time.perf_counter()
sys.path.insert(0, {root!r})
import numpy as np
import shading
t1 = time.perf_counter()
j = np.tile(np.arange(50.0), 50); i = np.repeat(np.arange(50.0), 50)
pos = np.stack([j / 49, np.ones(2500), i / 49], axis=1)
cam = shading.Camera.default_for_cloth(pos, 1, 1, width=256, height=256)
m = [shading.cloth_mesh(pos, 50, 50), shading.sphere_mesh((0.5, 0.2, 0.5), 0.2)]
shading.render(m, cam, None, {shader!r})
t2 = time.perf_counter()
print(t1 - t0, t2 - t1)
"""


def startup(shaders, cold):
    print(f"\n## start-up: new process, 256x256 sphere scene ({load()})")
    print(f"{'shader':<13} {'import s':>9} {'1st frame s':>12} {'total s':>8}"
          + (f" {'cold 1st frame s':>17}" if cold else ""))
    for sh in shaders:
        code = STARTUP.format(root=str(ROOT), shader=sh)
        cold_s = ""
        if cold:
            with tempfile.TemporaryDirectory() as d:
                env = dict(os.environ, NUMBA_CACHE_DIR=d)
                out = subprocess.run([sys.executable, "-c", code], env=env, check=True,
                                     capture_output=True, text=True).stdout.split()
                cold_s = f" {float(out[1]):17.2f}"
        best = None
        for _ in range(3):  # warm cache (the first run may still have to fill it)
            out = subprocess.run([sys.executable, "-c", code], check=True,
                                 capture_output=True, text=True).stdout.split()
            imp, first = float(out[0]), float(out[1])
            if best is None or imp + first < best[0] + best[1]:
                best = (imp, first)
        print(f"{sh:<13} {best[0]:9.3f} {best[1]:12.3f} {best[0] + best[1]:8.3f}{cold_s}",
              flush=True)


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="fewer repetitions")
    ap.add_argument("--shaders", default=",".join(shading.SHADERS))
    ap.add_argument("--stages", action="store_true", help="per-stage times")
    ap.add_argument("--startup", action="store_true", help="new-process start-up per shader")
    ap.add_argument("--cold", action="store_true", help="with --startup: cold compile too")
    ap.add_argument("--scaling", action="store_true", help="4x pixels time ratio")
    ap.add_argument("--looks", action="store_true",
                    help="shadows and ambient occlusion against the plain shader")
    ap.add_argument("--sizes", default="800x800,1920x1080")
    ap.add_argument("--cpu", action="store_true", help="CPU time of this thread")
    a = ap.parse_args(argv)
    if a.cpu:
        global clock
        clock = time.thread_time
    reps = 10 if a.quick else 40
    shaders = a.shaders.split(",")
    sizes = [tuple(int(v) for v in s.split("x")) for s in a.sizes.split(",")]
    header()
    if a.startup:
        startup(shaders, a.cold)
        return
    if a.looks:
        looks(shaders, sizes, max(reps // 4, 3))
        print(f"# {load()}")
        return
    if a.scaling:
        print(f"{'scene':<14} {'shader':<10} {'800x800 ms':>10} {'1600x1600 ms':>12} {'ratio':>6}")
        for name, pos, nw, nh, extra in scenes():
            for sh in shaders:
                t1 = bench(sh, pos, nw, nh, extra, 800, 800, reps)[1]
                t4 = bench(sh, pos, nw, nh, extra, 1600, 1600, reps)[1]
                print(f"{name:<14} {sh:<10} {t1 * 1e3:10.2f} {t4 * 1e3:12.2f} {t4 / t1:6.2f}",
                      flush=True)
        return
    cols = "".join(f" {k:>8}" for k in STAGES) if a.stages else ""
    print(f"{'scene':<14} {'size':>9} {'shader':<13} {'compile+1st s':>13} {'fps best':>8} "
          f"{'fps median':>10} {'fps render only':>15}" + cols)
    for name, pos, nw, nh, extra in scenes():
        for w, h in sizes:
            for sh in shaders:
                first, tb, tm, tr, stages = bench(sh, pos, nw, nh, extra, w, h, reps)
                cs = "".join(f" {stages[k] * 1e3:8.2f}" for k in STAGES) if a.stages else ""
                print(f"{name:<14} {w}x{h:<5} {sh:<13} {first:13.3f} {1 / tb:8.1f} "
                      f"{1 / tm:10.1f} {1 / tr:15.1f}" + cs, flush=True)
    print(f"# {load()}")


if __name__ == "__main__":
    main()

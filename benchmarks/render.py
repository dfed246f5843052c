"""Render benchmark: frames per second per shader.

    python benchmarks/render.py [--quick] [--shaders phong,normal]

Scenes: the sphere scene (50x50 cloth + sphere, frame 0 positions) and a 200x200 flat
cloth, at 800x800 and 1920x1080. Compile time (first call) is reported apart; warm
numbers are the median of timed renders into a reused Renderer (the finished uint8 image
included; no per-frame allocation of image buffers) plus the cloth mesh rebuild.
"""
from __future__ import annotations

import argparse
import statistics
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

import shading  # noqa: E402


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


def bench(shader, pos, nw, nh, extra, w, h, reps):
    cam = shading.Camera.default_for_cloth(pos, 1.0, 1.0, width=w, height=h)
    r = shading.Renderer(w, h)
    t0 = time.perf_counter()
    r.render([shading.cloth_mesh(pos, nw, nh)] + extra, cam, None, shader)
    first = time.perf_counter() - t0
    for _ in range(3):
        r.render([shading.cloth_mesh(pos, nw, nh)] + extra, cam, None, shader)
    times, rtimes = [], []
    for _ in range(reps):
        t0 = time.perf_counter()
        meshes = [shading.cloth_mesh(pos, nw, nh)] + extra
        t1 = time.perf_counter()
        r.render(meshes, cam, None, shader)
        t2 = time.perf_counter()
        times.append(t2 - t0)
        rtimes.append(t2 - t1)
    return first, statistics.median(times), statistics.median(rtimes)


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="fewer repetitions")
    ap.add_argument("--shaders", default=",".join(shading.SHADERS))
    a = ap.parse_args(argv)
    reps = 10 if a.quick else 40
    print(f"{'scene':<14} {'size':>9} {'shader':<13} {'compile+1st s':>13} "
          f"{'fps':>8} {'fps render only':>15}")
    for name, pos, nw, nh, extra in scenes():
        for w, h in ((800, 800), (1920, 1080)):
            for sh in a.shaders.split(","):
                first, t, tr = bench(sh, pos, nw, nh, extra, w, h, reps)
                print(f"{name:<14} {w}x{h:<5} {sh:<13} {first:13.3f} {1 / t:8.1f} {1 / tr:15.1f}",
                      flush=True)


if __name__ == "__main__":
    main()

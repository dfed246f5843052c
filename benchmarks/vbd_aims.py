"""Vertex Block Descent against the other integrators at equal error on screen (issue 44's
aims): for each VBD setting, its error over the shot against the converged physics, and
the cost of the cheapest other integrator that reaches that error.

    python benchmarks/vbd_aims.py                          # 50x50 and 100x100, 3000 and 30000 N/m
    python benchmarks/vbd_aims.py --sizes 50 --stretch 3000 --seconds 1   # a quick look

The case: scenes/pinned2.json under the FEM (two corners pinned, 90 frames a second), its
cloth n x n, `cloth.fem.stretch` set to S N/m with the shear scaled alike (as `render bench`'s
stability map does), over --seconds of simulated time. Error: the largest distance on
screen, in pixels of the scene's camera at its render size (fidelity auto's measure), of any
point between the run and the reference, over every --every-th frame. Cost: this process's
CPU time of the run on one numba thread (the work, without the waits other processes on
the machine cause).

The reference: Verlet at twice the steps of its stability floor (frame time / (0.9 dt_max),
dt_max from system.stability_limit); its uncertainty, a third of its distance from Verlet
at the floor (second order: halving the step takes 3/4 of the error away). The candidates:
Verlet at its floor (cheaper is unstable; more steps only lower an error already below every
other run's), implicit Euler at --implicit steps per frame, VBD at --vbd-steps steps per
frame x --iterations sweeps. A run the divergence guard stops has no error (x).

Prints one row per run (steps per frame, sweeps, error px, CPU s), then per VBD run the
cheapest other run whose error is at most VBD's, and the cost ratio VBD / that (the aim:
at most 0.2).
"""
from __future__ import annotations

import argparse
import math
import sys
import time
from dataclasses import replace
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

from pipeline.cli.bench import (Run, resized, scene_data, set_threads,  # noqa: E402
                                with_model, with_stiffness)
from pipeline.fidelity.controller import screen_distance  # noqa: E402
from pipeline.physics.system import stability_limit  # noqa: E402
from pipeline.scene import load_scene  # noqa: E402
from pipeline.view.framing import default_camera  # noqa: E402

MARGIN = 0.9  # Verlet's floor: this fraction of the stability limit


def case(n: int, stretch: float):
    """The pinned2 FEM scene at n x n and `stretch` N/m."""
    data = scene_data(ROOT / "scenes" / "pinned2.json")
    return load_scene(with_stiffness(with_model(resized(data, n, n), "fem"), "fem", stretch))


def run(scene, integrator, spf, frames, every, camera, reference=None, iterations=None):
    """(error px or nan, CPU s, positions at the sampled frames) of one run."""
    dt = 1.0 / (scene.simulation.frames_per_sec * spf)
    if iterations is not None:
        scene = replace(scene, simulation=replace(scene.simulation, iterations=iterations))
    r = Run(scene, integrator, dt=dt)
    kept, worst, cpu = [], 0.0, 0.0
    for f in range(1, frames + 1):
        t0 = time.process_time()
        ok = r.advance(spf)
        cpu += time.process_time() - t0
        if not ok:
            return math.nan, cpu, None
        if f % every == 0 or f == frames:
            x = r.x.T.copy()
            kept.append(x)
            if reference is not None:
                worst = max(worst, screen_distance(camera, x, reference[len(kept) - 1]))
    return worst, cpu, kept


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--sizes", default="50,100")
    ap.add_argument("--stretch", default="3000,30000")
    ap.add_argument("--seconds", type=float, default=3.0)
    ap.add_argument("--every", type=int, default=9, help="check every this many frames")
    ap.add_argument("--implicit", default="1,4,16", help="implicit Euler's steps per frame")
    ap.add_argument("--vbd-steps", default="1,2,4")
    ap.add_argument("--iterations", default="5,10,20")
    a = ap.parse_args(argv)
    set_threads(1)
    for n in (int(s) for s in a.sizes.split(",")):
        for stretch in (float(s) for s in a.stretch.split(",")):
            scene = case(n, stretch)
            fps = scene.simulation.frames_per_sec
            frames = round(a.seconds * fps)
            probe = Run(scene, "verlet")
            _, dt_max = stability_limit(probe.model)
            floor = math.ceil(1.0 / (fps * MARGIN * dt_max))
            camera = default_camera(scene, probe.model.x0.T, scene.render.width,
                                    scene.render.height)
            print(f"# {n}x{n}, stretch {stretch:g} N/m, {a.seconds:g} s ({frames} frames), "
                  f"dt_max {dt_max:.3g} s: Verlet's floor {floor} steps per frame", flush=True)
            _, ref_cpu, ref = run(scene, "verlet", 2 * floor, frames, a.every, camera)
            err, cpu, _ = run(scene, "verlet", floor, frames, a.every, camera, ref)
            print(f"reference: Verlet at {2 * floor} steps per frame ({ref_cpu:.1f} s); "
                  f"uncertainty {err / 3:.3g} px", flush=True)
            rows = [("verlet", floor, "", err * 4 / 3, cpu)]  # its error against the exact
            for spf in (int(s) for s in a.implicit.split(",")):
                e, c, _ = run(scene, "implicit-euler", spf, frames, a.every, camera, ref)
                rows.append(("implicit-euler", spf, "", e, c))
                print(f"  implicit-euler spf {spf}: {e:.3g} px, {c:.2f} s", flush=True)
            for spf in (int(s) for s in a.vbd_steps.split(",")):
                for it in (int(s) for s in a.iterations.split(",")):
                    e, c, _ = run(scene, "vbd", spf, frames, a.every, camera, ref, it)
                    rows.append(("vbd", spf, it, e, c))
                    print(f"  vbd spf {spf} x {it} sweeps: {e:.3g} px, {c:.2f} s", flush=True)
            print(f"{'integrator':<15} {'spf':>4} {'sweeps':>6} {'error px':>9} {'CPU s':>8} "
                  f"{'cheapest other at <= error':>27} {'ratio':>6}")
            others = [r for r in rows if r[0] != "vbd" and math.isfinite(r[3])]
            for name, spf, it, e, c in rows:
                line = f"{name:<15} {spf:>4} {it!s:>6} {e:>9.3g} {c:>8.2f}"
                if name == "vbd" and math.isfinite(e):
                    can = [r for r in others if r[3] <= e]
                    if can:
                        best = min(can, key=lambda r: r[4])
                        line += f" {best[0] + ' ' + str(best[1]):>27} {c / best[4]:>6.2f}"
                    else:
                        line += f" {'none':>27}"
                print(line, flush=True)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

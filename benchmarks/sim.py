"""Simulator benchmark: our numba kernels beside the C++ reference, in one run.

    python benchmarks/sim.py             # all cases
    python benchmarks/sim.py --quick     # fewer repeats
    python benchmarks/sim.py --features  # only the wind, mesh-collider and FEM cases (fast)
    python benchmarks/sim.py --mesh      # only the mesh-cloth cases against the grid

Per case: numba compile time (first call in a process with an empty cache, minus a warm call),
steps per second and seconds per simulated second (best of several runs, warm), the C++
reference's seconds on the same case and the time ratio ours / C++. Then cold and warm start
to the first frame (fresh processes) and the peak resident memory of `simulate` on 200x200
for 90 frames against the size of the returned array.

Feature cases (FEATURE_CASES, run in the same process, timed in alternation so that a busy
machine slows every variant alike; the C++ reference has neither feature): the pinned2 50x50
scene without wind, in a steady wind and in a gusty wind (cost of the aerodynamic forces per
step; target: wind at most 1.3x the step without), and the sphere 50x50 scene with its
analytic sphere against the same sphere as a 5120-triangle mesh collider
(scenes/meshes/icosphere5k.obj scaled to the sphere; target: at most 2x per step), plus the
one-off time to build the mesh's distance grid, and the pinned2 50x50 scene with the FEM
cloth model (`simulation.model: fem`, its default material) against the classic model, both
Verlet on the same grid with the same steps (target: FEM at most 2.5x per step), plus FEM
with implicit Euler for information (us/step and CG iterations per step). These cases always
take the best of at least 3 runs (they are short), --quick or not.

Mesh-cloth cases (MESH_SIZES, `--mesh` runs only these): the pinned2 scene at 50x50 and
100x100 against the same cloth given as a mesh (`cloth.mesh`: an OBJ of the grid's points,
in the grid's order, and its triangles, written to a temporary folder; the same two corners
pinned), under the classic model and under the FEM, each mesh timed in alternation with
the grid of the same points and model (target: a mesh cloth at most 1.2x the grid cloth per
step), self-collision off for both, at the scene's steps per frame or more where the
stability limit asks for them (the FEM: 34 and 67). The classic mesh has other springs than
the grid (the edges and one bending spring per interior edge, no shearing springs; about as
many in all); the FEM has the same elements.
"""
from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
REFERENCE = ROOT.parent / "shared" / "reference" / "cs184_ref"
CASES = [  # (label, scene file, grid size or None for the file's own)
    ("pinned2 50x50", "pinned2.json", None),
    ("pinned2 100x100", "pinned2.json", 100),
    ("pinned2 200x200", "pinned2.json", 200),
    ("sphere 50x50", "sphere.json", None),
    ("selfCollision 50x50", "selfCollision.json", None),
]
STEADY_WIND = {"velocity": [1.5, 0.0, 3.0]}
GUSTY_WIND = {"velocity": [1.5, 0.0, 3.0], "gust": 1.5, "gust_scale": 0.5, "gust_time": 0.5}
WIND_TARGET, MESH_TARGET, FEM_TARGET = 1.3, 2.0, 2.5  # per-step cost ratios to stay within
MESH_CLOTH_TARGET = 1.2  # a mesh cloth against the grid cloth of the same points and model
MESH_SIZES = (50, 100)
FEATURE_REPEATS = 3  # at least, even with --quick: the ratios need a best of several runs


def with_wind(raw: dict, wind: dict) -> dict:
    return dict(raw, wind=wind)


def sphere_as_mesh(raw: dict) -> dict:
    """The scene with its sphere replaced by the icosphere mesh scaled to the same sphere."""
    out = {k: v for k, v in raw.items() if k != "sphere"}
    sphere = raw["sphere"]
    out["mesh"] = {"path": str(ROOT / "scenes" / "meshes" / "icosphere5k.obj"),
                   "translation": sphere["origin"], "scale": sphere["radius"],
                   "friction": sphere["friction"]}
    return out


def with_simulation(raw: dict, **settings) -> dict:
    """The scene with these `simulation` keys set (e.g. model="fem", integrator=...)."""
    return dict(raw, simulation={**raw.get("simulation", {}), **settings})


FEATURE_CASES = [  # (label, scene file, change of the scene); each group's first is its base
    ("pinned2 50x50", "pinned2.json", None),
    ("  + steady wind", "pinned2.json", lambda raw: with_wind(raw, STEADY_WIND)),
    ("  + gusty wind", "pinned2.json", lambda raw: with_wind(raw, GUSTY_WIND)),
    ("  fem (verlet)", "pinned2.json", lambda raw: with_simulation(raw, model="fem")),
    ("  fem implicit-euler", "pinned2.json",
     lambda raw: with_simulation(raw, model="fem", integrator="implicit-euler")),
    ("sphere 50x50", "sphere.json", None),
    ("  icosphere5k mesh", "sphere.json", sphere_as_mesh),
]


def scene_dict(file: str, size: int | None) -> dict:
    raw = json.loads((ROOT / "scenes" / file).read_text())
    if size is not None:
        c = raw["cloth"]
        old = c["num_width_points"] - 1
        c["num_width_points"] = c["num_height_points"] = size
        c["pinned"] = [[x * (size - 1) // old, y * (size - 1) // old] for x, y in c.get("pinned", [])]
    return raw


def time_ours(raw: dict, repeats: int) -> tuple[float, int]:
    """Best wall time of one simulated second (frames_per_sec frames), warm."""
    import numpy as np  # noqa: F401  (imported before timing)

    from pipeline import Simulation, load_scene

    scene = load_scene(raw)
    frames = int(round(scene.simulation.frames_per_sec))
    sim = Simulation(scene)
    sim.advance(1)  # compile / load from cache
    best = float("inf")
    for _ in range(repeats):
        sim = Simulation(scene)
        t0 = time.perf_counter()
        sim.advance(frames)
        best = min(best, time.perf_counter() - t0)
    return best, frames * scene.simulation.steps_per_frame


def time_alternating(raws: list[dict], repeats: int) -> list[tuple[float, int, float, float]]:
    """(best wall time of one simulated second, steps, first Simulation() seconds, CG
    iterations per step or nan) of each scene, warm; the runs alternate between the scenes
    so that load from other processes hits every scene alike."""
    from pipeline import Simulation, load_scene

    scenes = [load_scene(raw) for raw in raws]
    setup = []
    for scene in scenes:
        t0 = time.perf_counter()
        sim = Simulation(scene)  # builds a mesh's distance grid (cached for later runs)
        setup.append(time.perf_counter() - t0)
        sim.advance(1)  # compile / load from cache
    best = [float("inf")] * len(scenes)
    cg = [float("nan")] * len(scenes)
    for _ in range(repeats):
        for k, scene in enumerate(scenes):
            sim = Simulation(scene)
            frames = int(round(scene.simulation.frames_per_sec))
            t0 = time.perf_counter()
            sim.advance(frames)
            best[k] = min(best[k], time.perf_counter() - t0)
            count = getattr(sim._state, "iterations", None)  # implicit Euler's CG total
            if count is not None:
                cg[k] = float(count[0]) / (frames * scene.simulation.steps_per_frame)
    return [(b, int(round(sc.simulation.frames_per_sec)) * sc.simulation.steps_per_frame, st, c)
            for b, sc, st, c in zip(best, scenes, setup, cg)]


def feature_cases(repeats: int) -> None:
    """The wind, mesh-collider and FEM cases, with their per-step ratios to the plain
    scenes."""
    raws = [change(scene_dict(file, None)) if change else scene_dict(file, None)
            for _, file, change in FEATURE_CASES]
    results = time_alternating(raws, max(repeats, FEATURE_REPEATS))
    per_step, cg_per_step = {}, {}
    for (label, _, _), (ours, steps, setup, cg) in zip(FEATURE_CASES, results):
        per_step[label] = ours / steps
        cg_per_step[label] = cg
        print(f"{label:22s} {float('nan'):9.2f} {steps / ours:9.0f} {ours:8.3f} {'n/a':>7s} "
              f"{'n/a':>6s} {ours / steps * 1e6:8.1f}")
    base = per_step["pinned2 50x50"]
    for label in ("  + steady wind", "  + gusty wind"):
        ratio = per_step[label] / base
        print(f"per step, pinned2 50x50 {label.strip()[2:]} / no wind: {ratio:.2f}x "
              f"(target <= {WIND_TARGET:g}x{'' if ratio <= WIND_TARGET else ': MISSED'})")
    ratio = per_step["  icosphere5k mesh"] / per_step["sphere 50x50"]
    print(f"per step, sphere 50x50 icosphere5k mesh / analytic sphere: {ratio:.2f}x "
          f"(target <= {MESH_TARGET:g}x{'' if ratio <= MESH_TARGET else ': MISSED'}); "
          f"setting up the mesh scene (distance grid) took {results[-1][2]:.2f} s")
    fem, implicit = per_step["  fem (verlet)"], per_step["  fem implicit-euler"]
    ratio = fem / base
    print(f"per step, pinned2 50x50 fem / classic (both verlet, same grid and steps): "
          f"{fem * 1e6:.1f} / {base * 1e6:.1f} us = {ratio:.2f}x "
          f"(target <= {FEM_TARGET:g}x{'' if ratio <= FEM_TARGET else ': MISSED'})")
    print(f"per step, pinned2 50x50 fem implicit-euler (information): {implicit * 1e6:.1f} us "
          f"= {implicit / fem:.2f}x fem verlet, "
          f"{cg_per_step['  fem implicit-euler']:.1f} CG iterations per step")


def grid_as_mesh(raw: dict, folder: Path) -> dict:
    """The scene with its grid cloth replaced by the same cloth as a mesh file: the grid's
    initial points (in the grid's order, so the pins keep their indices), its triangles and
    uvs, written as an OBJ into `folder`."""
    import numpy as np

    from pipeline import load_scene
    from pipeline.physics.model import build_model

    c = raw["cloth"]
    nw, nh = c["num_width_points"], c["num_height_points"]
    model = build_model(load_scene(raw))
    i, j = np.divmod(np.arange(nw * nh), nw)
    lines = ["v %r %r %r" % tuple(map(float, p)) for p in model.initial_positions]
    lines += ["vt %r %r" % (float(j[p]) / (nw - 1), float(i[p]) / (nh - 1))
              for p in range(nw * nh)]
    lines += ["f %d/%d %d/%d %d/%d" % tuple(np.repeat(t + 1, 2)) for t in model.triangles]
    obj = folder / f"grid{nw}x{nh}.obj"
    obj.write_text("\n".join(lines) + "\n")
    grid_keys = ("width", "height", "num_width_points", "num_height_points", "orientation",
                 "enable_shearing")
    cloth = {k: v for k, v in c.items() if k not in grid_keys}
    cloth["mesh"] = str(obj)
    cloth["pinned"] = [y * nw + x for x, y in c.get("pinned", [])]
    return dict(raw, cloth=cloth)


def stable_steps(raw: dict) -> int:
    """The scene's steps per frame, or more where Verlet needs them for the stability limit
    of the cloth or of the same cloth as a mesh (the FEM at 100x100: 67), with 15 %
    to spare."""
    import math

    from pipeline import Simulation

    import warnings

    with tempfile.TemporaryDirectory() as folder, warnings.catch_warnings():
        warnings.simplefilter("ignore")  # the StabilityWarning this answers
        dt_max = min(Simulation(r).dt_max for r in (raw, grid_as_mesh(raw, Path(folder))))
    sim = raw.get("simulation", {})
    fps = sim.get("frames_per_sec", 90)
    return max(sim.get("steps_per_frame", 30), math.ceil(1.15 / (fps * dt_max)))


def mesh_cases(repeats: int) -> None:
    """The mesh cloth against the grid cloth of the same points, per model and size."""
    with tempfile.TemporaryDirectory() as folder:
        labels, raws = [], []
        for size in MESH_SIZES:
            for model in ("classic", "fem"):
                # self-collision off for both, as the horizontal grid has it ("auto" turns
                # it on for a mesh cloth)
                grid = with_simulation(scene_dict("pinned2.json", size), model=model,
                                       self_collision=False)
                grid = with_simulation(grid, steps_per_frame=stable_steps(grid))
                labels += [f"{size}x{size} {model} grid", "  as a mesh"]
                raws += [grid, grid_as_mesh(grid, Path(folder))]
        results = time_alternating(raws, max(repeats, FEATURE_REPEATS))
    for label, (ours, steps, _, _) in zip(labels, results):
        print(f"{label:22s} {float('nan'):9.2f} {steps / ours:9.0f} {ours:8.3f} {'n/a':>7s} "
              f"{'n/a':>6s} {ours / steps * 1e6:8.1f}")
    for k in range(0, len(labels), 2):
        grid, mesh = (results[k][0] / results[k][1], results[k + 1][0] / results[k + 1][1])
        ratio = mesh / grid
        print(f"per step, pinned2 {labels[k][:-5]} mesh / grid: {mesh * 1e6:.1f} / "
              f"{grid * 1e6:.1f} us = "
              f"{ratio:.2f}x (target <= {MESH_CLOTH_TARGET:g}x"
              f"{'' if ratio <= MESH_CLOTH_TARGET else ': MISSED'})")


def time_reference(raw: dict, repeats: int) -> float | None:
    if not REFERENCE.is_dir():
        return None
    sys.path.insert(0, str(REFERENCE))
    import cs184_ref

    from pipeline import Simulation

    init = Simulation(raw).model.initial_positions  # same start (vertical cloth jitter)
    frames = int(raw.get("simulation", {}).get("frames_per_sec", 90))
    best = float("inf")
    for _ in range(repeats):
        _, info = cs184_ref.simulate(raw, frames, init_positions=init, last_only=True,
                                     timing=True, return_info=True)
        # the binary's own timer covers the stepping only, like ours
        fields = info["stderr"].split()
        best = min(best, float(fields[fields.index("sim_seconds") + 1]))
    return best


def compile_seconds(file: str) -> float:
    """First frame in a fresh process with an empty numba cache, minus a warm frame."""
    code = (
        "import time, json, pipeline\n"
        f"raw = json.load(open({str(ROOT / 'scenes' / file)!r}))\n"
        "t = time.perf_counter(); s = pipeline.Simulation(raw); s.advance(1)\n"
        "cold = time.perf_counter() - t\n"
        "t = time.perf_counter(); s = pipeline.Simulation(raw); s.advance(1)\n"
        "print(cold - (time.perf_counter() - t))\n"
    )
    with tempfile.TemporaryDirectory() as cache:
        env = dict(os.environ, NUMBA_CACHE_DIR=cache)
        out = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True,
                             text=True, check=True)
    return float(out.stdout.strip())


def start_to_first_frame(cache: str) -> float:
    code = "import pipeline; pipeline.simulate('scenes/pinned2.json', 1)"
    env = dict(os.environ, NUMBA_CACHE_DIR=cache)
    t0 = time.perf_counter()
    subprocess.run([sys.executable, "-c", code], env=env, cwd=ROOT, check=True)
    return time.perf_counter() - t0


def peak_memory_200() -> tuple[float, float, float]:
    """(peak RSS before, peak RSS after simulate(200x200, 90 frames), array MB)."""
    code = (
        "import resource, json, pipeline\n"
        "raw = json.loads(open('scenes/pinned2.json').read())\n"
        "pipeline.simulate(raw, 1)\n"  # compile, import everything
        "before = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024\n"
        "raw['cloth'].update(num_width_points=200, num_height_points=200,\n"
        "                    pinned=[[0, 0], [199, 0]])\n"
        "out = pipeline.simulate(raw, 90)\n"
        "after = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024\n"
        "print(before, after, out.nbytes / 2**20)\n"
    )
    out = subprocess.run([sys.executable, "-c", code], cwd=ROOT, capture_output=True, text=True,
                         check=True)
    before, after, array = map(float, out.stdout.split())
    return before, after, array


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="1 repeat instead of 3")
    ap.add_argument("--features", action="store_true",
                    help="only the wind, mesh-collider and FEM cases (no course cases, "
                         "start-up or memory figures)")
    ap.add_argument("--mesh", action="store_true",
                    help="only the mesh-cloth cases (a mesh of the grid's triangles against "
                         "the grid, both models)")
    args = ap.parse_args()
    repeats = 1 if args.quick else 3
    import numba

    print(f"numba {numba.__version__}, threads {numba.config.NUMBA_NUM_THREADS}, "
          f"cores {os.cpu_count()}")
    print(f"{'case':22s} {'compile s':>9s} {'steps/s':>9s} {'s/sim s':>8s} {'C++ s':>7s} "
          f"{'ratio':>6s} {'us/step':>8s}")
    if args.features or args.mesh:
        if args.features:
            feature_cases(repeats)
        if args.mesh:
            mesh_cases(repeats)
        return
    per_step = {}
    for label, file, size in CASES:
        raw = scene_dict(file, size)
        comp = compile_seconds(file) if size is None else float("nan")
        ours, steps = time_ours(raw, repeats)
        ref = time_reference(raw, repeats)
        per_step[label] = ours / steps
        ratio = f"{ours / ref:6.2f}" if ref else "   n/a"
        ref_s = f"{ref:7.3f}" if ref else "    n/a"
        print(f"{label:22s} {comp:9.2f} {steps / ours:9.0f} {ours:8.3f} {ref_s} {ratio} "
              f"{ours / steps * 1e6:8.1f}")
    base = per_step["pinned2 50x50"]
    print(f"per step, 200x200 / 50x50: {per_step['pinned2 200x200'] / base:.1f}x "
          f"(16x the points)")
    print(f"per step, selfCollision / pinned2 (50x50): "
          f"{per_step['selfCollision 50x50'] / base:.2f}x")
    feature_cases(repeats)
    mesh_cases(repeats)
    with tempfile.TemporaryDirectory() as cache:
        cold = start_to_first_frame(cache)
        warm = start_to_first_frame(cache)
    print(f"start to first frame (new process): cold {cold:.1f} s, warm {warm:.2f} s")
    before, after, array = peak_memory_200()
    print(f"simulate 200x200 x 90 frames: peak RSS {before:.0f} MB -> {after:.0f} MB "
          f"(+{after - before:.0f} MB; the returned array is {array:.0f} MB)")


if __name__ == "__main__":
    main()

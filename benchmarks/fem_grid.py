"""How far a coarser FEM grid lands from a fine one, on screen (docs/fidelity.md).

    python benchmarks/fem_grid.py [--grids 13,25,49,97] [--steps 160]
    python benchmarks/fem_grid.py --calibrate [--seconds 3]

For two FEM scenes (pinned2 held at two corners, swing held along its top edge): the same
cloth at nested grids (n - 1 divides the finest's n - 1), each at `--steps` steps per frame
with the drag rate held fixed, and the largest screen-space distance (the scene's camera,
512x512) between each coarser grid's points and the same material points of the finest
grid, every 0.5 s over 3 s. Prints a markdown table.

`--calibrate`: the calibration of fidelity auto's grid pilot (pipeline.fidelity.fem_grid) on
scenes/fem_sheet.json (97x97) and the swing at 49x49: the file's grid and its halvings, each
under fidelity auto at a quarter of a pixel (grid pilot off), and per grid the pilot's
prediction of its error against the file's grid (from the first second, as the pilot has
it) beside the largest error it actually reaches over the first second and over the shot.
"""
from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

import pipeline  # noqa: E402
from pipeline.fidelity.controller import metres_per_pixel, screen_distance
from pipeline.view.framing import default_camera

#: scene file, pins of an n x n grid, the FEM overrides of the classic file
SCENES = {
    "pinned2": lambda n: [[0, 0], [n - 1, 0]],
    "swing": lambda n: [[j, n - 1] for j in range(n)],
}


def scene_at(name: str, n: int, steps: int) -> dict:
    data = json.loads((ROOT / "scenes" / f"{name}.json").read_text())
    spf = data.get("simulation", {}).get("steps_per_frame", 30)
    damping = data["cloth"]["damping"] / 100.0
    data["cloth"].update(num_width_points=n, num_height_points=n, pinned=SCENES[name](n),
                         damping=(1.0 - (1.0 - damping) ** (spf / steps)) * 100.0)
    data.setdefault("simulation", {}).update(model="fem", steps_per_frame=steps)
    return data


def run(data: dict, seconds: float = 3.0):
    """(positions (nh, nw, 3) every 0.5 s, the Simulation)."""
    sim = pipeline.Simulation(data)
    fps = round(sim.scene.simulation.frames_per_sec)
    every = max(1, fps // 2)
    n = sim.model.nw
    out = []
    for f in range(1, round(seconds * fps) + 1):
        sim.advance(1)
        if f % every == 0:
            out.append(sim.positions.copy().reshape(sim.model.nh, n, 3))
    return out, sim


def calibrate(name: str, overrides: list[str], seconds: float) -> None:
    """Print the pilot's predictions against the errors reached (module docstring)."""
    from pipeline.fidelity.fem_grid import Spline, coarse_pins, coarse_scene, coarse_size, decide

    scene = pipeline.load_scene(ROOT / "scenes" / f"{name}.json", overrides + [
        "simulation.fidelity=auto", "simulation.tolerance_px=0.25"])
    c = scene.cloth
    sizes = [(coarse_size(c.num_width_points, k), coarse_size(c.num_height_points, k))
             for k in range(4)]
    sims = [pipeline.Simulation(coarse_scene(scene, w, h, coarse_pins(
        c.pinned, *sizes[0], w, h)), shot_seconds=seconds, grid=False) for w, h in sizes]
    camera = sims[0].stepper.camera
    fps = scene.simulation.frames_per_sec
    at = [Spline(w, h, *sizes[-1]) for w, h in sizes]  # every grid at G3's points
    neighbour = np.zeros((2, len(sizes) - 1))  # largest over the first second, the shot
    to_file = np.zeros((2, len(sizes)))
    for f in range(1, round(seconds * fps) + 1):
        for sim in sims:
            sim.advance(1)
        x = [s(sim.positions) for s, sim in zip(at, sims)]
        row = int(f > fps)
        for k in range(len(sizes) - 1):
            neighbour[row, k] = max(neighbour[row, k], screen_distance(camera, x[k], x[k + 1]))
        for k in range(1, len(sizes)):
            to_file[row, k] = max(to_file[row, k], screen_distance(camera, x[0], x[k]))
    first, shot = neighbour[0], neighbour.max(axis=0)
    ratio, predicted, _ = decide(first[2], first[1], 1.0)
    print(f"{name} {sizes[0][0]}x{sizes[0][1]}: largest distance between neighbouring grids "
          f"over 1 s {' '.join(f'{d:.2f}' for d in first)} px, over {seconds:g} s "
          f"{' '.join(f'{d:.2f}' for d in shot)} px; ratio D32/D21 {ratio:.2f}")
    print("| grid | predicted error (px) | error over 1 s (px) | error over the shot (px) |")
    print("|---|---:|---:|---:|")
    for k in range(1, len(sizes)):
        print(f"| {sizes[k][0]}x{sizes[k][1]} | {predicted[k - 1]:.2f} | {to_file[0, k]:.2f} | "
              f"{to_file.max(axis=0)[k]:.2f} |", flush=True)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--grids", default="13,25,49,97")
    ap.add_argument("--steps", type=int, default=160)
    ap.add_argument("--calibrate", action="store_true")
    ap.add_argument("--seconds", type=float, default=3.0)
    args = ap.parse_args(argv)
    import numba

    numba.set_num_threads(1)
    if args.calibrate:
        calibrate("fem_sheet", [], args.seconds)
        calibrate("swing", ["cloth.num_width_points=49", "cloth.num_height_points=49",
                            "cloth.pinned=" + json.dumps([[j, 48] for j in range(49)])],
                  args.seconds)
        return 0
    grids = sorted(int(g) for g in args.grids.split(","))
    finest = grids[-1]
    print("| scene (FEM) | grid | cell on screen | error vs finest, every 0.5 s (px) |")
    print("|---|---|---:|---|")
    for name in SCENES:
        runs = {n: run(scene_at(name, n, args.steps))[0] for n in grids[:-1]}
        fine, sim = run(scene_at(name, finest, args.steps))
        camera = default_camera(sim.scene, sim.model.x0.T, 512, 512)
        mpp = metres_per_pixel(camera, sim.model.x0.T)
        for n in grids[:-1]:
            k = (finest - 1) // (n - 1)
            errors = [screen_distance(camera, c.reshape(-1, 3), f[::k, ::k].reshape(-1, 3))
                      for c, f in zip(runs[n], fine)]
            cell = sim.model.width / (n - 1) / mpp
            print(f"| {name} | {n}x{n} | {cell:.0f} px | "
                  f"{' '.join(f'{e:.1f}' for e in errors)} |", flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())

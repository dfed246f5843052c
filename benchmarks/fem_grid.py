"""How far a coarser FEM grid lands from a fine one, on screen (docs/fidelity.md).

    python benchmarks/fem_grid.py [--grids 13,25,49,97] [--steps 160]

For two FEM scenes (pinned2 held at two corners, swing held along its top edge): the same
cloth at nested grids (n - 1 divides the finest's n - 1), each at `--steps` steps per frame
with the drag rate held fixed, and the largest screen-space distance (the scene's camera,
512x512) between each coarser grid's points and the same material points of the finest
grid, every 0.5 s over 3 s. Prints a markdown table.
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
from pipeline.fidelity import metres_per_pixel, screen_distance  # noqa: E402
from pipeline.frames import default_camera  # noqa: E402

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


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--grids", default="13,25,49,97")
    ap.add_argument("--steps", type=int, default=160)
    args = ap.parse_args(argv)
    import numba

    numba.set_num_threads(1)
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

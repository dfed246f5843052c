"""Soak: every scene in scenes/ under every integrator for a long simulated time.

    python benchmarks/soak.py                    # 30 s of simulated time per run
    python benchmarks/soak.py --seconds 5 --scenes sphere,curtain --integrators verlet
    python benchmarks/soak.py --markdown docs/soak.md

Each (scene, integrator) runs in a fresh process (`--one`), so that memory figures are
the run's own. Per run: whether the simulation diverged (the guard's message), the most
free cloth points found inside a collider after any frame (a point is inside when the
colliders' own projection, at that frame's time and with friction 0, moves it by more than
INSIDE_TOLERANCE; planes act only on crossings, so they never count; with friction the
course's collision rule itself leaves a resting point partly inside, so the deepest such
point is reported too), the growth of the
resident memory from the end of the first frame (kernels compiled, state allocated) to its
peak, sampled every frame, and the wall time. The table goes to stdout (and to a Markdown
file with --markdown).
"""
from __future__ import annotations

import argparse
import json
import subprocess
import sys
import time
import warnings
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

INSIDE_TOLERANCE = 1e-6  # metres: a projection moving a point less than this is rounding


def _rss_bytes() -> int:
    with open("/proc/self/statm") as fh:
        import os

        return int(fh.read().split()[1]) * os.sysconf("SC_PAGE_SIZE")


def run_one(scene_file: str, integrator: str, seconds: float) -> dict:
    """Simulate one scene with one integrator; the measurements as a dict."""
    import numpy as np

    from pipeline.physics.overlap import project_out, still_table
    from pipeline.scene import load_scene
    from pipeline.physics.errors import DivergenceError
    from pipeline.simulation import Simulation

    scene = load_scene(scene_file, [f"simulation.integrator={integrator}"])
    t0 = time.perf_counter()
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        sim = Simulation(scene)
    frames = round(seconds * scene.simulation.frames_per_sec)
    table = still_table(scene.colliders)
    pinned = sim.model.pinned
    result = {"scene": Path(scene_file).stem, "integrator": integrator, "frames": frames,
              "diverged": None, "frames_done": 0, "max_inside": 0, "max_depth_mm": 0.0,
              "rss_growth_mb": 0.0,
              "warnings": [str(w.message).splitlines()[0] for w in caught]}
    rss_start = peak = None
    try:
        for f in range(frames):
            sim.advance(1)
            x = np.ascontiguousarray(sim.positions.T)
            moved = x.copy()
            project_out(moved, pinned, table, sim.time)
            depth = np.sqrt(((moved - x) ** 2).sum(axis=0))
            result["max_inside"] = max(result["max_inside"], int((depth > INSIDE_TOLERANCE).sum()))
            result["max_depth_mm"] = max(result["max_depth_mm"], 1000 * float(depth.max()))
            result["frames_done"] = f + 1
            rss = _rss_bytes()
            if rss_start is None:
                rss_start = peak = rss
            peak = max(peak, rss)
    except DivergenceError as exc:
        result["diverged"] = str(exc).strip().splitlines()[0]
    if rss_start is not None:
        result["rss_growth_mb"] = (peak - rss_start) / 2**20
    result["wall_s"] = time.perf_counter() - t0
    return result


def _row(r: dict) -> str:
    status = f"diverged: {r['diverged']}" if r["diverged"] else "no"
    return (f"| {r['scene']} | {r['integrator']} | {r['frames_done']}/{r['frames']} | {status} "
            f"| {r['max_inside']} | {r['max_depth_mm']:.1f} | {r['rss_growth_mb']:.1f} | {r['wall_s']:.0f} |")


HEADER = ("| scene | integrator | frames | diverged | max points inside colliders | "
          "max depth (mm) | peak RSS growth (MB) | wall (s) |\n|---|---|---|---|---|---|---|---|")


def main(argv=None) -> int:
    from pipeline.scene import INTEGRATORS

    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--seconds", type=float, default=30.0, help="simulated seconds per run")
    p.add_argument("--scenes", help="comma-separated scene names (default: all in scenes/)")
    p.add_argument("--integrators", default=",".join(INTEGRATORS))
    p.add_argument("--markdown", help="also write the table to this Markdown file")
    p.add_argument("--one", nargs=2, metavar=("SCENE", "INTEGRATOR"), help=argparse.SUPPRESS)
    args = p.parse_args(argv)
    if args.one:
        print(json.dumps(run_one(args.one[0], args.one[1], args.seconds)))
        return 0
    names = (args.scenes.split(",") if args.scenes
             else sorted(f.stem for f in (ROOT / "scenes").glob("*.json")))
    rows = []
    print(HEADER, flush=True)
    for name in names:
        for integrator in args.integrators.split(","):
            r = subprocess.run([sys.executable, __file__, "--seconds", str(args.seconds),
                                "--one", str(ROOT / "scenes" / f"{name}.json"), integrator],
                               capture_output=True, text=True)
            if r.returncode != 0:
                last = (r.stderr.strip().splitlines() or ["(no message)"])[-1]
                result = {"scene": name, "integrator": integrator, "frames": 0,
                          "frames_done": 0, "diverged": f"run failed: {last}", "max_inside": 0,
                          "max_depth_mm": 0.0,
                          "rss_growth_mb": 0.0, "wall_s": 0.0}
            else:
                result = json.loads(r.stdout.strip().splitlines()[-1])
            rows.append(result)
            print(_row(result), flush=True)
    if args.markdown:
        Path(args.markdown).write_text(
            f"{HEADER}\n" + "\n".join(_row(r) for r in rows) + "\n", encoding="utf-8")
    return 0


if __name__ == "__main__":
    sys.exit(main())

"""Self-collision at scale: what it costs per step, through a whole shot, against the same
cloth without it, measured alternately in one process.

    python benchmarks/self_collision.py                 # 50x50 and 100x100, 4 s; the drape
    python benchmarks/self_collision.py --sizes 50 --seconds 2 --rounds 2

selfCollision (the course scene: a vertical cloth falling onto a plane, piling up) at each
grid, with `simulation.self_collision` true and false: the seconds of each simulated second
of the shot (the first falls, the later ones pile up), warm, the two variants in turn,
best of --rounds; the ratio per step (the aim: at most 2.5x the cloth without it, every
second of the shot). Then the drape: an 80x80 cloth with self-collision dropped over the
course's sphere onto a floor, 3 s of animation (the aim: at most 4 s to simulate). The
numba threads are the process's own (clothjit.THREADS: one per free core); the load
average is printed. --cpu times the process's CPU time instead of the wall (steadier on a
busy machine; the same figure as the wall with NUMBA_NUM_THREADS=1 on a quiet one).
"""
from __future__ import annotations

import argparse
import os
import time

from sim import scene_dict  # benchmarks/sim.py: a course scene resized, pins moved along

PER_STEP_AIM = 2.5
DRAPE_AIM = 4.0  # seconds of simulate for 3 s of animation


def self_collision_scene(size: int, on: bool) -> dict:
    raw = scene_dict("selfCollision.json", size)
    raw["simulation"] = {**raw.get("simulation", {}), "self_collision": on}
    return raw


def drape_scene(size: int = 80) -> dict:
    raw = scene_dict("sphere.json", size)
    raw["plane"] = {"point": [0, 0, 0], "normal": [0, 1, 0], "friction": 0.5}
    raw["simulation"] = {**raw.get("simulation", {}), "self_collision": True}
    return raw


def seconds_per_second(raw: dict, seconds: int, clock=time.perf_counter) -> list[float]:
    """Seconds (wall, or `clock`'s) of each simulated second of a fresh run of `raw`."""
    from pipeline import Simulation

    sim = Simulation(raw)
    fps = int(round(sim.scene.simulation.frames_per_sec))
    out = []
    for _ in range(seconds):
        t0 = clock()
        sim.advance(fps)
        out.append(clock() - t0)
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--sizes", default="50,100", help="grids of selfCollision (default 50,100)")
    ap.add_argument("--seconds", type=int, default=4, help="simulated seconds (default 4)")
    ap.add_argument("--rounds", type=int, default=3, help="runs of each variant (best kept)")
    ap.add_argument("--no-drape", action="store_true", help="skip the 80x80 drape")
    ap.add_argument("--cpu", action="store_true",
                    help="time the process's CPU time (all threads) instead of the wall")
    args = ap.parse_args()
    clock = time.process_time if args.cpu else time.perf_counter

    import clothjit
    from pipeline import Simulation, load_scene

    print(f"# {time.strftime('%Y-%m-%d %H:%M')}, {os.cpu_count()} cores, numba threads "
          f"{clothjit.THREADS}, {'CPU time' if args.cpu else 'wall'}, load average "
          f"{' '.join(f'{x:.2f}' for x in os.getloadavg())}")
    for size in (int(s) for s in args.sizes.split(",")):
        raws = {on: self_collision_scene(size, on) for on in (True, False)}
        for raw in raws.values():  # load the kernels from the cache (or compile them)
            Simulation(raw).advance(1)
        best = {on: [float("inf")] * args.seconds for on in raws}
        for _ in range(args.rounds):
            for on, raw in raws.items():
                times = seconds_per_second(raw, args.seconds, clock)
                best[on] = [min(a, b) for a, b in zip(best[on], times)]
        settings = load_scene(raws[True]).simulation
        steps = int(round(settings.frames_per_sec)) * settings.steps_per_frame
        print(f"selfCollision {size}x{size}, best of {args.rounds}: us per step in each "
              "simulated second")
        print(f"{'second':>8} {'with':>10} {'without':>10} {'ratio':>7}")
        for k in range(args.seconds):
            on, off = best[True][k] / steps * 1e6, best[False][k] / steps * 1e6
            flag = "" if on / off <= PER_STEP_AIM else "  over the aim"
            print(f"{k + 1:>8} {on:10.1f} {off:10.1f} {on / off:7.2f}{flag}")
    if not args.no_drape:
        raw = drape_scene()
        Simulation(raw).advance(1)
        runs = [sum(seconds_per_second(raw, 3, clock)) for _ in range(args.rounds)]
        print(f"drape 80x80 over a sphere onto a floor, self-collision on: {min(runs):.2f} s "
              f"(best of {args.rounds}; runs {', '.join(f'{r:.2f}' for r in runs)}) for 3 s of "
              f"animation (aim <= {DRAPE_AIM:g} s)")


if __name__ == "__main__":
    main()

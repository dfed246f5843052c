"""Contact benchmark (issue 43): does the cloth pass through itself, how close do its layers
come, and what does the contact cost.

    python benchmarks/contact.py                                   # every scene, course contact
    python benchmarks/contact.py --scenes selfCollision,strip --contact robust
    python benchmarks/contact.py --contact course,robust           # both, one after the other
    python benchmarks/contact.py --scenes drape --seconds 1

Per scene and checked frame: the edge-triangle crossing count of the checker in
benchmarks/crossings.py (written apart from the solver: every cloth edge against every
triangle sharing no vertex with it; exact degenerate contacts counted apart as "touching"),
the smallest distance between non-neighbouring elements (vertex-triangle and edge-edge pairs
sharing no vertex and further apart than `thickness` in the first frame, as issue 43 counts
them) in units of the cloth's thickness, to set against 2 (self-collision keeps points
2 x thickness apart; ">3" when no pair is within 3 x thickness), and the simulate time so
far (sim.advance only: the checker's time is printed apart). A flat cloth's nearest such
pairs are its own neighbours in the plane (the grid spacing / thickness, or its diagonal's
half): the frame-0 figure is that floor.

Scenes (the checker runs on every frame of selfCollision and the strip, every fifth frame of
the drape, by default):
- selfCollision: scenes/selfCollision.json (50x50, vertical, falling onto a plane), 2.5 s.
- strip: a 0.2 m x 3 m vertical strip (11 x 151 points, the course's spacing 0.02 m, the
  course cloth's material), standing on a floor, with self-collision on: it sinks under
  its own weight and buckles into folds piling up on the floor, 3 s.
- drape: scenes/sphere.json at 80x80 (a horizontal cloth at y = 1 over the sphere of radius
  0.2 resting on the floor) with a floor plane and self-collision on, 3 s.

`--contact MODE` is passed as the override `simulation.contact=MODE`. While the scene format
does not know `simulation.contact`, the course behaviour runs: MODE course silently, any other
MODE with the words "contact mode not available". Each scene's kernels are loaded (or
compiled) by one untimed frame before the timed run.
"""
from __future__ import annotations

import argparse
import json
import os
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))

from crossings import edge_triangle_contacts, min_separation, unique_edges

ROOT = Path(__file__).resolve().parents[1]
SEP_RADIUS = 3.0  # separations searched up to this many thicknesses
SEP_REFERENCE = 2.0  # ... and set against this many


def _course(file: str) -> dict:
    return json.loads((ROOT / "scenes" / file).read_text())


def self_collision_scene() -> dict:
    return _course("selfCollision.json")


def strip_scene() -> dict:
    raw = _course("selfCollision.json")
    raw["cloth"].update(width=0.2, height=3.0, num_width_points=11, num_height_points=151,
                        orientation=1)
    raw["simulation"] = {**raw.get("simulation", {}), "self_collision": True}
    return raw


def drape_scene() -> dict:
    raw = _course("sphere.json")
    raw["cloth"].update(num_width_points=80, num_height_points=80)
    raw["plane"] = {"point": [0, 0, 0], "normal": [0, 1, 0], "friction": 0.5}
    raw["simulation"] = {**raw.get("simulation", {}), "self_collision": True}
    return raw


#: name: (scene dict builder, default seconds, check every n-th frame)
SCENES = {
    "selfCollision": (self_collision_scene, 2.5, 1),
    "strip": (strip_scene, 3.0, 1),
    "drape": (drape_scene, 3.0, 5),
}


def load_with_contact(raw: dict, mode: str):
    """(Scene, note): the scene under `simulation.contact=mode`, or the course behaviour with
    a note when the format does not take that mode."""
    from pipeline import SceneError, load_scene

    try:
        return load_scene(raw, [f"simulation.contact={mode}"]), ""
    except SceneError as e:
        if mode == "course":
            return load_scene(raw), ""
        return load_scene(raw), f"contact mode not available ({e}); the course contact runs"


def ranges(frames: list[int]) -> str:
    """[3, 4, 5, 9] -> '3-5, 9'."""
    out, start = [], None
    for k, f in enumerate(frames):
        if start is None:
            start = f
        if k + 1 == len(frames) or frames[k + 1] != f + 1:
            out.append(f"{start}" if start == f else f"{start}-{f}")
            start = None
    return ", ".join(out) or "none"


def run_scene(name: str, mode: str, seconds: float | None, every: int | None) -> dict:
    from pipeline import DivergenceError, Simulation

    build, default_seconds, default_every = SCENES[name]
    seconds = default_seconds if seconds is None else seconds
    every = default_every if every is None else every
    scene, note = load_with_contact(build(), mode)
    ran = mode if not note else "course"
    Simulation(scene).advance(1)  # kernels from the cache (or compiled): untimed
    sim = Simulation(scene)
    tris = sim.model.triangles
    rest = sim.positions.copy()
    thick = scene.cloth.thickness
    fps = scene.simulation.frames_per_sec
    frames = round(seconds * fps)
    c = scene.cloth
    shape = (f"{c.num_width_points}x{c.num_height_points} grid" if c.mesh is None
             else "mesh")
    print(f"\n== {name}, contact {mode}{' (ran: course)' if note else ''}: {shape}, "
          f"{len(rest)} points, {len(tris)} triangles, {len(unique_edges(tris))} edges, "
          f"thickness {thick:g} m, self-collision {'on' if scene.self_collision else 'off'}, "
          f"{scene.simulation.integrator}, {scene.simulation.steps_per_frame} steps/frame; "
          f"{seconds:g} s = {frames} frames, checked every {every}")
    if note:
        print(f"   {note}")
    print(f"{'frame':>6} {'time':>6} {'crossings':>9} {'touching':>8} "
          f"{'sep/thick':>9} {'sim s':>7} {'check s':>7}")
    rows, sim_s, check_s, error = [], 0.0, 0.0, ""

    def check(frame: int) -> None:
        nonlocal check_s
        t0 = time.perf_counter()
        pos = sim.positions
        cont = edge_triangle_contacts(pos, tris)
        sep = min_separation(pos, tris, SEP_RADIUS * thick, rest_points=rest, rest_min=thick)
        check_s += time.perf_counter() - t0
        n = len(cont.crossings)
        rows.append((frame, n, len(cont.touching), sep / thick))
        sep_text = f"{sep / thick:9.4f}" if sep < float("inf") else f"{'>' + str(SEP_RADIUS):>9}"
        print(f"{frame:6d} {frame / fps:6.3f} {n:9d} {len(cont.touching):8d} {sep_text} "
              f"{sim_s:7.2f} {check_s:7.2f}", flush=True)

    check(0)
    for frame in range(1, frames + 1):
        t0 = time.perf_counter()
        try:
            sim.advance(1)
        except DivergenceError as e:
            error = f"diverged at frame {frame}: {e}"
            print(f"   {error}")
            break
        sim_s += time.perf_counter() - t0
        if frame % every == 0 or frame == frames:
            check(frame)

    counts = [r[1] for r in rows]
    crossed = [r[0] for r in rows if r[1] > 0]
    seps = [r[3] for r in rows[1:]] or [r[3] for r in rows]
    low = min(seps)
    low_frame = rows[1:][seps.index(low)][0] if len(rows) > 1 else 0
    summary = (f"{name} [{mode}{'->course' if note else ''}]: {len(rows)} frames checked, "
               f"crossings min {min(counts)} max {max(counts)} (at frame "
               f"{rows[counts.index(max(counts))][0]}), {len(crossed)} frames with crossings: "
               f"{ranges(crossed)}; touching in {sum(r[2] > 0 for r in rows)} frames; "
               f"smallest separation {low:.4f} thickness at frame {low_frame} (frame 0: "
               f"{rows[0][3]:.4f}; reference {SEP_REFERENCE:g}); simulate {sim_s:.2f} s, "
               f"checker {check_s:.2f} s" + (f"; {error}" if error else ""))
    print(summary)
    return {"name": name, "mode": mode, "ran": ran, "sim_s": sim_s, "summary": summary,
            "max": max(counts), "crossed": len(crossed)}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--scenes", default=",".join(SCENES),
                    help=f"comma-separated, of {', '.join(SCENES)} (default: all)")
    ap.add_argument("--contact", default="course",
                    help="contact mode, or modes comma-separated, run in turn (default course)")
    ap.add_argument("--seconds", type=float, default=None,
                    help="simulated seconds of every scene (default: 2.5 selfCollision, "
                         "3 strip, 3 drape)")
    ap.add_argument("--every", type=int, default=None,
                    help="check every n-th frame (default: 1 selfCollision and strip, 5 drape)")
    args = ap.parse_args(argv)
    names = [s.strip() for s in args.scenes.split(",") if s.strip()]
    bad = [n for n in names if n not in SCENES]
    if bad:
        ap.error(f"unknown scene(s) {', '.join(bad)}: choose from {', '.join(SCENES)}")
    modes = [m.strip() for m in args.contact.split(",") if m.strip()]

    import clothjit

    print(f"# {time.strftime('%Y-%m-%d %H:%M')}, {os.cpu_count()} cores, numba threads "
          f"{clothjit.THREADS}, load average {' '.join(f'{x:.2f}' for x in os.getloadavg())}")
    results = [run_scene(n, m, args.seconds, args.every) for n in names for m in modes]
    print("\n== summary")
    for r in results:
        print(r["summary"])
    if "course" in modes and len(modes) > 1:
        for n in names:
            base = next(r for r in results if r["name"] == n and r["mode"] == "course")
            for r in results:
                if r["name"] == n and r["mode"] != "course" and base["sim_s"] > 0:
                    print(f"{n}: {r['mode']} simulate {r['sim_s']:.2f} s = "
                          f"{r['sim_s'] / base['sim_s']:.2f} x course ({base['sim_s']:.2f} s)")
    return 0


if __name__ == "__main__":
    sys.exit(main())

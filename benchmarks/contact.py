"""Contact benchmark (issue 43): does the cloth pass through itself or a collider, how close
do its layers come, and what does the contact cost.

    python benchmarks/contact.py                                   # every scene, course contact
    python benchmarks/contact.py --scenes selfCollision,strip --contact robust
    python benchmarks/contact.py --contact course,robust           # both, one after the other
    python benchmarks/contact.py --scenes drape --seconds 1
    python benchmarks/contact.py --scenes rising,twist,pile,garment --seconds 0.3  # smoke test
    python benchmarks/contact.py --scenes bowl,sweep,openbowl --contact course,robust  # meshes

Per scene and checked frame: the edge-triangle crossing count of the checker in
benchmarks/crossings.py (written apart from the solver: every cloth edge against every
triangle sharing no vertex with it; exact degenerate contacts counted apart as "touching"),
the smallest distance between non-neighbouring elements (vertex-triangle and edge-edge pairs
sharing no vertex and further apart than `thickness` in the first frame, as issue 43 counts
them) in units of the cloth's thickness, to set against 2 (self-collision keeps points
2 x thickness apart; ">3" when no pair is within 3 x thickness), then the collider columns
of the independent checker benchmarks/collider_crossings.py at the frame's simulated time
(pins left out as it does), summed over the scene's colliders (a point or edge caught by two
colliders counts twice): `inside`, free points strictly inside a solid collider (sphere,
box, solid mesh), and `edges`, cloth edges through a solid collider, across a one-sided
mesh or across a plane; `y mid`, the median height of the cloth's points in metres (where
the cloth is: on the rising sphere, carried or left behind); and the simulate time so far
(sim.advance only, from the second frame on: the first loads or compiles the kernels, and
its time and the checker's are printed apart). A flat cloth's nearest such pairs
are its own neighbours in the plane (the grid spacing / thickness, or its diagonal's half):
the frame-0 figure is that floor. The summary line gives, per scene, the crossing and
separation figures and the collider columns' largest value (and its frame), their total over
the checked frames and the frames where either is non-zero.

Scenes (default seconds; the checker runs on every frame of selfCollision and the strip,
every fifth frame of the others, and every frame of the rising sphere from 0.95 s on):
- selfCollision: scenes/selfCollision.json (50x50, vertical, falling onto a plane), 2.5 s.
- strip: a 0.2 m x 3 m vertical strip (11 x 151 points, the course's spacing 0.02 m, the
  course cloth's material), standing on a floor, with self-collision on: it sinks under
  its own weight and buckles into folds piling up on the floor, 3 s.
- drape: scenes/sphere.json at 80x80 (a horizontal cloth at y = 1 over the sphere of radius
  0.2 resting on the floor) with a floor plane and self-collision on, 3 s.
- rising: a free 40 x 40 horizontal cloth (0.8 m at y = 1, the course material, thickness
  0.0095) falls 0.1 m onto a sphere (radius 0.25, top at y = 0.9, friction 0.5) and lies on
  it; the sphere is keyframed still until t = 1.0 s, then rises at 10 m/s for 0.15 s (1.5 m)
  and is held; a floor at y = 0; self-collision on; 1.6 s. It must carry the cloth.
- twist: a 0.6 m square mesh cloth (an OBJ of a 31 x 31 grid, at y = 1, the course
  material) whose two opposite edges (x = -0.3 and x = +0.3) are held by keyframed box pins,
  each turned one full turn about the x axis (the line joining the edge centres), in
  opposite directions, from t = 0 to 2.5 s, then held; self-collision on; 3 s. From about
  0.2 s the hands hold the edges further apart than Provot's limit lets the cloth reach:
  under robust contact the limit stops there (the summary says so).
- pile: one mesh cloth of three pieces (`"pieces": "allow"`): 0.6 m squares of 31 x 31
  vertices in one OBJ, stacked 5 cm apart (y = 0.5, 0.55, 0.6) and turned 0, 15 and 30
  degrees about the vertical, dropped on a box 0.3 m wide and 0.4 m high on a floor;
  self-collision on; 2 s.
- garment: scenes/tshirt.json as it is (a mesh T-shirt on a mesh torso, 60 fps x 48 steps)
  with self-collision on, 3 s.
- bowl: scenes/bowl.json as it is (a 40 x 40 cloth dropped over a solid concave mesh bowl
  of 4096 triangles on a floor), no self-collision (the colliders alone), 2 s.
- sweep: a 30 x 30 cloth hanging from two corners, swept up through by a keyframed mesh
  ball (the 5120 triangles of scenes/meshes/icosphere5k.obj at radius 0.15) rising 1 m in
  0.2 s from t = 0.2 s and turning; no self-collision; 0.8 s, every frame checked while it
  passes. It must carry the cloth.
- openbowl: a 40 x 40 cloth dropped onto the one-sided open shell
  scenes/meshes/open_bowl.obj (radius 0.4, 1984 triangles, `"solid": false`); no
  self-collision; 2 s. Going round the rim is no crossing; through the shell is.
The meshes of twist and pile are written at run time into a temporary folder, removed at
exit. On 2 shared cores a robust run of each new scene at its default length takes a few
minutes at most (simulate, 2026-11: pile 50 s for its first second, twist 14 s, garment
3.4 s for its first 1.5 s).

`--contact MODE` is passed as the override `simulation.contact=MODE`. While the scene format
does not know `simulation.contact`, the course behaviour runs: MODE course silently, any other
MODE with the words "contact mode not available". Each scene's kernels are loaded (or
compiled) by one untimed frame before the timed run. `--set KEY=VALUE` (repeatable) adds a
scene override to every scene (an integrator, the model, steps per frame). A run the
solver stops as diverged ends its scene there: the summary says so.
"""
from __future__ import annotations

import argparse
import atexit
import importlib.util
import json
import math
import os
import shutil
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent


def _load(name: str):
    """benchmarks/<name>.py, loaded by its path (benchmarks/ on sys.path would shadow Dask's
    `distributed` with benchmarks/distributed.py); reused when already loaded."""
    if name in sys.modules:
        return sys.modules[name]
    spec = importlib.util.spec_from_file_location(name, HERE / f"{name}.py")
    module = importlib.util.module_from_spec(spec)
    sys.modules[name] = module
    spec.loader.exec_module(module)
    return module


_crossings = _load("crossings")  # before collider_crossings, which reuses it
edge_triangle_contacts = _crossings.edge_triangle_contacts
min_separation = _crossings.min_separation
unique_edges = _crossings.unique_edges
collider_violations = _load("collider_crossings").collider_violations

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


#: the course cloth's material (scenes/selfCollision.json), for the built scenes
COURSE_MATERIAL = {"thickness": 0.0095, "damping": 0.2, "density": 150.0, "ks": 5000.0}
RISE_START, RISE_SECONDS, RISE_SPEED = 1.0, 0.15, 10.0  # the rising sphere: s, s, m/s
TWIST_SECONDS = 2.5  # the twist's full turn of each held edge
_TMP: list[Path] = []


def _tmp_dir() -> Path:
    """A temporary folder for the generated meshes, removed at exit."""
    if not _TMP:
        _TMP.append(Path(tempfile.mkdtemp(prefix="contact-bench-")))
        atexit.register(shutil.rmtree, _TMP[0], True)
    return _TMP[0]


def grid_obj(n: int, size: float, layers: int = 1, gap: float = 0.0,
             turns_deg: tuple[float, ...] = (0.0,)) -> str:
    """OBJ text of `layers` horizontal squares of n x n vertices and side `size`, centred on
    the y axis, layer k at y = k * gap and turned turns_deg[k] degrees about y; each cell
    split into two triangles along alternating diagonals (no preferred direction)."""
    lines, base = [], 0
    for k in range(layers):
        a = math.radians(turns_deg[k % len(turns_deg)])
        ca, sa = math.cos(a), math.sin(a)
        for j in range(n):
            for i in range(n):
                x, z = size * (i / (n - 1) - 0.5), size * (j / (n - 1) - 0.5)
                lines.append(f"v {ca * x + sa * z:.9f} {k * gap:.9f} {-sa * x + ca * z:.9f}")
        for j in range(n - 1):
            for i in range(n - 1):
                a00, a10 = base + j * n + i + 1, base + j * n + i + 2  # OBJ: 1-based
                a01, a11 = a00 + n, a10 + n
                if (i + j) % 2 == 0:
                    lines += [f"f {a00} {a10} {a11}", f"f {a00} {a11} {a01}"]
                else:
                    lines += [f"f {a00} {a10} {a01}", f"f {a10} {a11} {a01}"]
        base += n * n
    return "\n".join(lines) + "\n"


def _write_obj(name: str, text: str) -> str:
    path = _tmp_dir() / name
    path.write_text(text)
    return str(path)


def rising_scene() -> dict:
    """A free 40 x 40 horizontal cloth (0.8 m, at y = 1) falls 0.1 m onto a sphere (radius
    0.25, top at y = 0.9) and lies on it; from RISE_START the sphere rises at RISE_SPEED
    for RISE_SECONDS (1.5 m), then is held. A floor at y = 0."""
    rise = RISE_SPEED * RISE_SECONDS
    return {
        "cloth": {"width": 0.8, "height": 0.8, "num_width_points": 40, "num_height_points": 40,
                  "orientation": 0, "enable_structural": True, "enable_shearing": True,
                  "enable_bending": True, **COURSE_MATERIAL},
        "sphere": {"origin": [0.4, 0.65, 0.4], "radius": 0.25, "friction": 0.5,
                   "keyframes": [{"time": RISE_START},
                                 {"time": RISE_START + RISE_SECONDS,
                                  "translation": [0, rise, 0]}]},
        "plane": {"point": [0, 0, 0], "normal": [0, 1, 0], "friction": 0.5},
        "simulation": {"self_collision": True},
    }


def twist_scene() -> dict:
    """A 0.6 m square mesh cloth (31 x 31 vertices, at y = 1) held along its two edges at
    x = -0.3 and x = +0.3 by keyframed box pins, each edge turned one full turn about the x
    axis (the line joining the edge centres), in opposite directions, over TWIST_SECONDS."""
    obj = _write_obj("twist.obj", grid_obj(31, 0.6))
    e = 0.005  # the boxes catch one column of points (spacing 0.02 m)

    def held(x: float, turn: float) -> dict:
        return {"box": [[x - e, 1 - e, -0.3 - e], [x + e, 1 + e, 0.3 + e]],
                "keyframes": [{"time": 0}, {"time": TWIST_SECONDS, "rotation": [turn, 0, 0]}]}

    return {
        "cloth": {"mesh": obj, "translation": [0, 1, 0], **COURSE_MATERIAL,
                  "pinned": [held(-0.3, 360.0), held(0.3, -360.0)]},
        "simulation": {"self_collision": True},
    }


def pile_scene() -> dict:
    """One mesh cloth of three pieces: 0.6 m squares of 31 x 31 vertices stacked 5 cm apart
    (y = 0.5, 0.55, 0.6; turned 0, 15 and 30 degrees about the vertical), dropped on a box
    0.3 m wide whose top is at y = 0.4, on a floor."""
    obj = _write_obj("pile.obj", grid_obj(31, 0.6, layers=3, gap=0.05,
                                          turns_deg=(0.0, 15.0, 30.0)))
    return {
        "cloth": {"mesh": obj, "translation": [0, 0.5, 0], "pieces": "allow",
                  **COURSE_MATERIAL},
        "box": {"center": [0, 0.2, 0], "half_extents": [0.15, 0.2, 0.15], "friction": 0.5},
        "plane": {"point": [0, 0, 0], "normal": [0, 1, 0], "friction": 0.5},
        "simulation": {"self_collision": True},
    }


def garment_scene() -> dict:
    """scenes/tshirt.json as it is (its mesh paths made absolute), self-collision on."""
    raw = _course("tshirt.json")
    raw["cloth"]["mesh"] = str(ROOT / "scenes" / raw["cloth"]["mesh"])
    for m in raw["mesh"] if isinstance(raw["mesh"], list) else [raw["mesh"]]:
        m["path"] = str(ROOT / "scenes" / m["path"])
    raw["simulation"] = {**raw.get("simulation", {}), "self_collision": True}
    return raw


def bowl_scene() -> dict:
    """scenes/bowl.json as it is (a 40 x 40 cloth dropped over a solid concave mesh bowl
    on a floor; its mesh path made absolute); no self-collision: the colliders only."""
    raw = _course("bowl.json")
    raw["mesh"]["path"] = str(ROOT / "scenes" / raw["mesh"]["path"])
    return raw


SWEEP_START, SWEEP_SECONDS, SWEEP_RISE = 0.2, 0.2, 1.0  # the swept mesh: s, s, m


def sweep_scene() -> dict:
    """A 30 x 30 cloth (1 m at y = 1) hanging from two corners, swept up through from
    SWEEP_START by a keyframed mesh ball (scenes/meshes/icosphere5k.obj at radius 0.15)
    rising SWEEP_RISE in SWEEP_SECONDS (5 m/s) and turning, then held."""
    return {
        "cloth": {"width": 1, "height": 1, "num_width_points": 30, "num_height_points": 30,
                  "orientation": 0, "enable_structural": True, "enable_shearing": True,
                  "enable_bending": True, "pinned": [[0, 0], [29, 0]], **COURSE_MATERIAL},
        "mesh": {"path": str(ROOT / "scenes" / "meshes" / "icosphere5k.obj"),
                 "translation": [0.5, 0.7, 0.5], "scale": 0.15, "friction": 0.5,
                 "thickness": 0.005,
                 "keyframes": [{"time": SWEEP_START},
                               {"time": SWEEP_START + SWEEP_SECONDS,
                                "translation": [0, SWEEP_RISE, 0], "rotation": [0, 90, 0]}]},
    }


def open_bowl_scene() -> dict:
    """A 40 x 40 cloth (1.2 m at y = 1) dropped onto the one-sided open hemispherical shell
    scenes/meshes/open_bowl.obj (radius 0.4, rim at y = 0.5): into it, round its rim."""
    return {
        "cloth": {"width": 1.2, "height": 1.2, "num_width_points": 40, "num_height_points": 40,
                  "orientation": 0, "enable_structural": True, "enable_shearing": True,
                  "enable_bending": True, **COURSE_MATERIAL},
        "mesh": {"path": str(ROOT / "scenes" / "meshes" / "open_bowl.obj"),
                 "translation": [0.6, 0.5, 0.6], "solid": False, "friction": 0.4,
                 "thickness": 0.008},
        "simulation": {"frames_per_sec": 60, "steps_per_frame": 15},
    }


#: name: (scene dict builder, default seconds, check every n-th frame, and every frame
#: within (from, to) seconds or None)
SCENES = {
    "selfCollision": (self_collision_scene, 2.5, 1, None),
    "strip": (strip_scene, 3.0, 1, None),
    "drape": (drape_scene, 3.0, 5, None),
    "rising": (rising_scene, 1.6, 5, (RISE_START - 0.05, 1.6)),
    "twist": (twist_scene, 3.0, 5, None),  # the full turn and its hold
    "pile": (pile_scene, 2.0, 5, None),
    "garment": (garment_scene, 3.0, 5, None),
    "bowl": (bowl_scene, 2.0, 5, None),
    "sweep": (sweep_scene, 0.8, 5, (SWEEP_START, SWEEP_START + SWEEP_SECONDS + 0.05)),
    "openbowl": (open_bowl_scene, 2.0, 5, None),
}


def load_with_contact(raw: dict, mode: str, extra: tuple[str, ...] = ()):
    """(Scene, note): the scene under `simulation.contact=mode` (and the `extra` overrides),
    or the course behaviour with a note when the format does not take that mode."""
    from pipeline import SceneError, load_scene

    try:
        return load_scene(raw, [f"simulation.contact={mode}", *extra]), ""
    except SceneError as e:
        if mode == "course":
            return load_scene(raw, list(extra)), ""
        return (load_scene(raw, list(extra)),
                f"contact mode not available ({e}); the course contact runs")


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


def run_scene(name: str, mode: str, seconds: float | None, every: int | None,
              extra: tuple[str, ...] = ()) -> dict:
    from pipeline import DivergenceError, Simulation

    build, default_seconds, default_every, window = SCENES[name]
    seconds = default_seconds if seconds is None else seconds
    every = default_every if every is None else every
    scene, note = load_with_contact(build(), mode, extra)
    ran = mode if not note else "course"
    Simulation(scene).advance(1)  # kernels from the cache (or compiled): untimed
    sim = Simulation(scene)
    tris = sim.model.triangles
    edges = unique_edges(tris)
    pinned = sim.model.pinned
    rest = sim.positions.copy()
    thick = scene.cloth.thickness
    fps = scene.simulation.frames_per_sec
    frames = round(seconds * fps)
    dense = (range(0) if window is None else
             range(math.ceil(window[0] * fps - 1e-9), math.floor(window[1] * fps + 1e-9) + 1))
    c = scene.cloth
    shape = (f"{c.num_width_points}x{c.num_height_points} grid" if c.mesh is None
             else "mesh")
    print(f"\n== {name}, contact {mode}{' (ran: course)' if note else ''}: {shape}, "
          f"{len(rest)} points, {len(tris)} triangles, {len(unique_edges(tris))} edges, "
          f"thickness {thick:g} m, self-collision {'on' if scene.self_collision else 'off'}, "
          f"{scene.simulation.integrator}, {scene.simulation.steps_per_frame} steps/frame; "
          f"{seconds:g} s = {frames} frames, checked every {every}"
          + (f" and every frame {dense.start}-{dense.stop - 1}" if len(dense) else ""))
    kinds = ", ".join(type(o).__name__ for o in scene.colliders)
    print(f"   colliders: {kinds} ({'robust' if ran == 'robust' else 'course'}"
          f" handling; inside/edges: collider_crossings, summed over the colliders)"
          if kinds else "   colliders: none")
    if extra:
        print(f"   overrides: {' '.join(extra)}")
    if note:
        print(f"   {note}")
    print(f"{'frame':>6} {'time':>6} {'crossings':>9} {'touching':>8} "
          f"{'sep/thick':>9} {'inside':>6} {'edges':>6} {'y mid':>6} {'sim s':>7} {'check s':>7}")
    rows, sim_s, first_s, check_s, error = [], 0.0, 0.0, 0.0, ""

    def check(frame: int) -> None:
        nonlocal check_s
        t0 = time.perf_counter()
        pos = sim.positions
        cont = edge_triangle_contacts(pos, tris)
        sep = min_separation(pos, tris, SEP_RADIUS * thick, rest_points=rest, rest_min=thick)
        v = collider_violations(pos, edges, scene.colliders, sim.time, pinned)
        inside = sum(len(c["inside"]) for c in v["colliders"])
        through = sum(len(c["edges"]) for c in v["colliders"])
        check_s += time.perf_counter() - t0
        n = len(cont.crossings)
        y_mid = float(np.median(pos[:, 1]))
        rows.append((frame, n, len(cont.touching), sep / thick, inside, through, y_mid))
        sep_text = f"{sep / thick:9.4f}" if sep < float("inf") else f"{'>' + str(SEP_RADIUS):>9}"
        print(f"{frame:6d} {frame / fps:6.3f} {n:9d} {len(cont.touching):8d} {sep_text} "
              f"{inside:6d} {through:6d} {y_mid:6.3f} {sim_s:7.2f} {check_s:7.2f}", flush=True)

    check(0)
    for frame in range(1, frames + 1):
        t0 = time.perf_counter()
        try:
            sim.advance(1)
        except DivergenceError as e:
            error = f"diverged at frame {frame}: {e}"
            print(f"   {error}")
            break
        if frame == 1:
            first_s = time.perf_counter() - t0
        else:
            sim_s += time.perf_counter() - t0
        if frame % every == 0 or frame == frames or frame in dense:
            check(frame)

    counts = [r[1] for r in rows]
    crossed = [r[0] for r in rows if r[1] > 0]
    seps = [r[3] for r in rows[1:]] or [r[3] for r in rows]
    low = min(seps)
    low_frame = rows[1:][seps.index(low)][0] if len(rows) > 1 else 0
    ins, thr = [r[4] for r in rows], [r[5] for r in rows]
    hit = [r[0] for r in rows if r[4] or r[5]]
    summary = (f"{name} [{mode}{'->course' if note else ''}]: {len(rows)} frames checked, "
               f"crossings min {min(counts)} max {max(counts)} (at frame "
               f"{rows[counts.index(max(counts))][0]}), {len(crossed)} frames with crossings: "
               f"{ranges(crossed)}; touching in {sum(r[2] > 0 for r in rows)} frames; "
               f"smallest separation {low:.4f} thickness at frame {low_frame} (frame 0: "
               f"{rows[0][3]:.4f}; reference {SEP_REFERENCE:g}); colliders: points inside "
               f"max {max(ins)} (at frame {rows[ins.index(max(ins))][0]}) total {sum(ins)}, "
               f"edges through max {max(thr)} (at frame {rows[thr.index(max(thr))][0]}) total "
               f"{sum(thr)}, {len(hit)} frames with either: {ranges(hit)}; y mid at frame "
               f"{rows[-1][0]} {rows[-1][6]:.3f} m; simulate {sim_s:.2f} s (the first "
               f"frame, loading the kernels, {first_s:.2f} s apart), checker {check_s:.2f} s" + (f"; {error}" if error else ""))
    stop = sim.limit_stop
    if stop is not None:
        summary += f"; {stop.note}"
    print(summary)
    return {"name": name, "mode": mode, "ran": ran, "sim_s": sim_s, "summary": summary,
            "max": max(counts), "crossed": len(crossed), "inside_max": max(ins),
            "edges_max": max(thr), "collider_frames": len(hit)}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--scenes", default=",".join(SCENES),
                    help=f"comma-separated, of {', '.join(SCENES)} (default: all)")
    ap.add_argument("--contact", default="course",
                    help="contact mode, or modes comma-separated, run in turn (default course)")
    ap.add_argument("--seconds", type=float, default=None,
                    help="simulated seconds of every scene (default: " + ", ".join(
                        f"{v[1]:g} {k}" for k, v in SCENES.items()) + ")")
    ap.add_argument("--every", type=int, default=None,
                    help="check every n-th frame (default: 1 selfCollision and strip, 5 the "
                         "others; rising also every frame from 0.95 s)")
    ap.add_argument("--set", action="append", default=[], metavar="KEY=VALUE",
                    help="a scene override for every scene (e.g. simulation.steps_per_frame=60, "
                         "simulation.integrator=xpbd); repeatable")
    args = ap.parse_args(argv)
    names = [s.strip() for s in args.scenes.split(",") if s.strip()]
    bad = [n for n in names if n not in SCENES]
    if bad:
        ap.error(f"unknown scene(s) {', '.join(bad)}: choose from {', '.join(SCENES)}")
    modes = [m.strip() for m in args.contact.split(",") if m.strip()]

    import clothjit

    print(f"# {time.strftime('%Y-%m-%d %H:%M')}, {os.cpu_count()} cores, numba threads "
          f"{clothjit.THREADS}, load average {' '.join(f'{x:.2f}' for x in os.getloadavg())}")
    results = [run_scene(n, m, args.seconds, args.every, tuple(args.set))
               for n in names for m in modes]
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

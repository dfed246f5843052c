"""Robust contact (`simulation.contact` "robust"): the self-contact (pipeline.physics.contact)
judged by the independent checker benchmarks/crossings.py, and the colliders
(pipeline.physics.collider_contact) by benchmarks/collider_crossings.py and by a path check of
this file's own (every point's straight path over a step, in the collider's rest frame, must
not pass through the solid); both checkers are written apart from the solver. One file, so
that one worker compiles robust contact's kernels once."""
from __future__ import annotations

import dataclasses
import json
import importlib.util
import sys
from pathlib import Path

import numpy as np
import pytest

from conftest import scene_path
from pipeline import Simulation, load_scene
from pipeline.physics.collider_contact import FACE_PUSHES, MOVED_OUT, PIN_POINT
from pipeline.physics.contact import contact_summary, pack_contact, robust_contact


def _checker():
    spec = importlib.util.spec_from_file_location(
        "crossings", Path(__file__).resolve().parents[1] / "benchmarks" / "crossings.py")
    module = importlib.util.module_from_spec(spec)
    sys.modules.setdefault("crossings", module)
    spec.loader.exec_module(module)
    return module


crossings = _checker()


def self_collision_scene(mode: str, n: int = 20):
    return load_scene(scene_path("selfCollision"), [
        f"simulation.contact={mode}", f"cloth.num_width_points={n}",
        f"cloth.num_height_points={n}"])


def crossing_counts(mode: str, frames: int = 90, every: int = 3):
    sim = Simulation(self_collision_scene(mode))
    counts = []
    for f in range(frames):
        sim.advance(1)
        if f % every == 0:
            counts.append(crossings.edge_triangle_crossings(sim.positions, sim.model.triangles))
    return counts, sim


def test_the_course_cloth_passes_through_itself_and_the_robust_one_never_does():
    """selfCollision at 20 x 20 for its first 0.62 s: the course's point repulsion lets the
    folding cloth through itself from about 0.44 s; robust contact never (every third
    frame checked)."""
    course, _ = crossing_counts("course", 56, 3)
    robust, sim = crossing_counts("robust", 56, 3)
    assert max(course) > 50 and sum(c > 0 for c in course) >= 5
    assert max(robust) == 0
    stats = sim.system.contact.stats
    assert stats[1] > 0  # it did push pairs apart
    # and no point of the cloth, which starts with its lowest row on the floor, left pushed
    # through the floor (the independent collider checker)
    v = CC.collider_violations(sim.positions, crossings.unique_edges(sim.model.triangles),
                               sim.scene.colliders, sim.time, sim.model.pinned)
    assert [(len(c["inside"]), len(c["edges"])) for c in v["colliders"]] == [(0, 0)]


def test_robust_contact_is_deterministic():
    runs = []
    for _ in range(2):
        sim = Simulation(self_collision_scene("robust"))
        sim.advance(40)
        runs.append(sim.positions.tobytes())
    assert runs[0] == runs[1]


def test_a_candidate_list_that_overflows_gets_room_and_the_same_motion(monkeypatch):
    """A cloth as thick as 0.76 of its spacing (as the 80x80 drape) lists dozens of pairs a
    point; with room for one, the list overflows (the steps visit the hash), the simulation
    makes room for them all, and the cloth moves exactly as with room from the start; the
    list is then in use."""
    import pipeline.physics.contact as contact

    runs = {}
    for per in (64, 1):
        monkeypatch.setattr(contact, "LISTED_PER_POINT", per)
        sim = Simulation(load_scene(scene_path("selfCollision"), [
            "simulation.contact=robust", "cloth.num_width_points=20",
            "cloth.num_height_points=20", "cloth.thickness=0.04"]))
        sim.advance(20)
        runs[per] = (sim.positions.tobytes(), sim.system.contact)
    tight = runs[1][1]
    n = tight.rest.shape[1]
    assert runs[1][0] == runs[64][0]
    assert tight.listed.shape[0] >= 4 * n and tight.count[0] >= 0


def test_the_fail_safe_holds_what_the_passes_cannot_resolve():
    """A small triangle driven down through a stack of 30 free layers 2 mm apart in one
    step: the stops, averaged per point, push layers through each other faster than their
    rounds settle, so the fail-safe holds the points of the pairs still meeting where they
    were. Every layer and the small triangle end on the side of every other they started
    on (their planes stay parallel: the order of their heights at the middle)."""
    layers = 30
    tris, points = [], []
    for k in range(layers):
        points += [(-1.0, 0.002 * k, -1.0), (1.0, 0.002 * k, -1.0), (0.0, 0.002 * k, 1.0)]
        tris.append((3 * k, 3 * k + 1, 3 * k + 2))
    base = len(points)
    points += [(0.0, 0.5, 0.0), (0.05, 0.5, 0.0), (0.0, 0.5, 0.05)]
    tris.append((base, base + 1, base + 2))
    x0 = np.ascontiguousarray(np.array(points, dtype=np.float64).T)
    x1 = x0.copy()
    x1[1, base:] -= 0.8  # through every layer to below the stack
    c = pack_contact(1e-4, 0.0, np.array(tris), x0, np.ones(x0.shape[1]),
                     np.zeros(x0.shape[1], np.uint8))
    robust_contact(x1, x0, c)
    assert c.stats[2] > 0 and c.stats[3] > 0 and c.stats[4] == 0  # stops, then the fail-safe
    assert crossings.edge_triangle_crossings(x1.T, np.array(tris)) == 0
    # each layer's height where the small triangle is (x = z = 0.02): the order is kept
    height = []
    for k in range(layers):
        a, b, d = x1[:, 3 * k], x1[:, 3 * k + 1], x1[:, 3 * k + 2]
        normal = np.cross(b - a, d - a)
        height.append(a[1] - (normal[0] * (0.02 - a[0]) + normal[2] * (0.02 - a[2])) / normal[1])
    assert np.all(np.diff(height) > 0) and x1[1, base:].min() > max(height)


def test_pins_forced_through_the_cloth_are_reported_not_hidden():
    """A pinned triangle moved through a pinned point: no point can move, the pair is
    counted as unresolvable."""
    x0 = np.ascontiguousarray(np.array([(-1.0, 0.0, -1.0), (1.0, 0.0, -1.0), (0.0, 0.0, 1.0),
                                        (0.0, 0.1, 0.0), (0.1, 0.1, 0.0), (0.0, 0.1, 0.1)]).T)
    x1 = x0.copy()
    x1[1, :3] += 0.5
    c = pack_contact(1e-3, 0.0, np.array([(0, 1, 2), (3, 4, 5)]), x0, np.ones(6),
                     np.ones(6, np.uint8))
    robust_contact(x1, x0, c)
    assert c.stats[4] > 0


@pytest.mark.parametrize("integrator", ["implicit-euler", "xpbd"])  # Verlet: above
def test_every_integrator_keeps_the_cloth_from_crossing_itself(integrator):
    scene = load_scene(scene_path("selfCollision"), [
        "simulation.contact=robust", "cloth.num_width_points=16",
        "cloth.num_height_points=16", f"simulation.integrator={integrator}"])
    sim = Simulation(scene)
    for f in range(60):
        sim.advance(1)
        if f % 6 == 5:
            assert crossings.edge_triangle_crossings(sim.positions, sim.model.triangles) == 0


def test_the_solvers_own_crossing_count_agrees_with_the_checker(rng):
    """contact.tangles (used to report a cloth that starts tangled) against the independent
    checker on folded, crumpled states of a grid cloth."""
    from pipeline.physics.contact import tangles

    sim = Simulation(self_collision_scene("course", 24))
    c = pack_contact(0.01, 0.0, sim.model.triangles, sim.model.x0, sim.model.point_mass,
                     sim.model.pinned)
    out = np.zeros((4, 2), np.int64)
    seen = 0
    for _ in range(6):
        sim.advance(12)
        x = np.ascontiguousarray(sim.positions.T)
        expected = crossings.edge_triangle_crossings(sim.positions, sim.model.triangles)
        assert tangles(x, c, out) == expected
        seen += expected
    assert seen > 0


def test_a_cloth_that_starts_tangled_is_reported_before_the_run():
    from pipeline.physics.errors import StartTangledWarning

    scene = self_collision_scene("course", 24)
    sim = Simulation(scene)
    sim.advance(45)  # crumpled and crossed by the course's contact
    tangled = sim.positions.copy()
    assert crossings.edge_triangle_crossings(tangled, sim.model.triangles) > 0
    robust = self_collision_scene("robust", 24)
    with pytest.warns(StartTangledWarning, match=r"edge-triangle crossings? at t = 0 \(e.g. "
                                                 r"the edge between points \[\d+, \d+\]"):
        Simulation(robust, initial_positions=tangled)


def test_render_plan_and_the_summary_say_what_contact_ran(tmp_path, capsys):
    from pipeline.cli import main

    assert main(["plan", str(scene_path("selfCollision")), "--contact", "robust"]) == 0
    assert "self-collision: robust contact on every step" in capsys.readouterr().out
    out = tmp_path / "x.gif"
    assert main([str(scene_path("selfCollision")), "--contact", "robust", "--set",
                 "cloth.num_width_points=12", "--set", "cloth.num_height_points=12",
                 "--duration", "0.1", "--out", str(out)]) == 0
    err = capsys.readouterr().err
    assert "robust contact:" in err and "pairs tested a step" in err and out.exists()


def test_a_mesh_cloth_dropped_on_another_piece_does_not_pass_through_it(tmp_path):
    """A mesh of two pieces (pieces "allow"): a square falling onto a held one below it
    stays on top under robust contact, which pushed and stopped pairs to keep it there."""
    from test_mesh_cloth import write_obj
    from test_mesh_model import grid_mesh

    points, tris, corner_uv = grid_mesh(9, 9, 1.0, 1.0)
    low = np.stack([points[:, 0], np.full(len(points), 0.5), points[:, 1]], 1)
    high = low + np.array([0.05, 0.08, 0.05])
    obj = write_obj(tmp_path / "two.obj", np.concatenate([low, high]),
                    np.concatenate([tris, tris + len(points)]),
                    np.concatenate([corner_uv, corner_uv]))
    held = [0, 8, 72, 80]  # the lower square's corners
    scene = {"cloth": {"mesh": str(obj), "pieces": "allow", "thickness": 0.01,
                       "damping": 0.2, "density": 1.0, "ks": 1000.0, "pinned": held},
             "simulation": {"self_collision": True, "contact": "robust"}}
    sim = Simulation(scene)
    sim.advance(30)
    assert crossings.edge_triangle_crossings(sim.positions, sim.model.triangles) == 0
    assert sim.positions[len(points):, 1].mean() > sim.positions[:len(points), 1].mean()
    assert sim.system.contact.stats[1] > 0  # the layers met: pushed apart


def _folded_cloth(n: int, h: float, seed: int):
    """A flat n x n grid of 0.3 m folded in half onto itself 0.8 h apart, jittered: (rest
    (3, N), positions (3, N), triangles (T, 3))."""
    rng = np.random.default_rng(seed)
    u, v = np.meshgrid(np.linspace(0, 0.3, n), np.linspace(0, 0.3, n))
    rest = np.stack([u.ravel(), np.zeros(n * n), v.ravel()])
    x = rest.copy()
    far = x[0] > 0.15
    x[0, far] = 0.3 - x[0, far]
    x[1, far] = 0.8 * h
    x += rng.normal(scale=0.2 * h, size=x.shape)
    a = (np.arange(n - 1)[None, :] + n * np.arange(n - 1)[:, None]).ravel()
    tris = np.concatenate([np.stack([a, a + 1, a + n], 1), np.stack([a + 1, a + n + 1, a + n], 1)])
    return rest, np.ascontiguousarray(x), tris


def _listed_against_brute_force(h: float, skins=None):
    """A 20 x 20 fold's candidate list made afresh (with these skins, in h, else the first
    list's) and the pairs that brute force (the checker's distances, every pair) finds
    within h plus the pair's skins (each primitive's the largest of its points') and not
    within h at rest: (listed rows, expected set)."""
    from pipeline.physics import contact

    rest, x, tris = _folded_cloth(20, h, 0)
    n = x.shape[1]
    c = pack_contact(h, 0.3, tris, rest, np.ones(n), np.zeros(n, np.uint8))
    c = c._replace(listed=np.zeros((256 * n, 5), np.int64), listed_gap=np.zeros(256 * n))
    if skins is not None:
        c.anchor[3] = skins * h
    skin = c.anchor[3].copy()
    contact._round(x, x, contact.RobustContact(*c[:-1], None), c.visit, 0)
    assert c.count[0] >= 0  # it fitted
    listed = [tuple(int(v) for v in row) for row in c.listed[:c.count[0]]]
    points, at_rest = x.T, rest.T
    expected = set()
    for p in range(n):
        tri = tris[~np.any(tris == p, axis=1)]
        reach = h + skin[p] + skin[tri].max(axis=1)
        near = crossings.point_triangle_distance(np.repeat(points[p][None], len(tri), 0),
                                                 *(points[tri[:, j]] for j in range(3))) <= reach
        apart = ~(crossings.point_triangle_distance(
            np.repeat(at_rest[p][None], len(tri), 0), *(at_rest[tri[:, j]] for j in range(3))) < h)
        expected |= {(p, *map(int, t), 0) for t in tri[near & apart]}
    edges = crossings.unique_edges(tris)
    for i, (a, b) in enumerate(edges):
        other = edges[i + 1:]
        other = other[~np.any((other == a) | (other == b), axis=1)]
        reach = h + max(skin[a], skin[b]) + skin[other].max(axis=1)
        ends = [np.repeat(q[[a, b]][:, None], len(other), 1) for q in (points, at_rest)]
        near = crossings.segment_segment_distance(*ends[0], points[other[:, 0]],
                                                  points[other[:, 1]]) <= reach
        apart = ~(crossings.segment_segment_distance(*ends[1], at_rest[other[:, 0]],
                                                     at_rest[other[:, 1]]) < h)
        expected |= {(int(a), int(b), *map(int, e), 1) for e in other[near & apart]}
    return listed, expected


def test_the_candidate_list_is_every_pair_within_twice_the_thickness_once():
    """The first list (every point's skin half the thickness): the pairs within 2 h that
    are not neighbours at rest, each once."""
    listed, expected = _listed_against_brute_force(0.008)
    assert len(listed) == len(set(listed))
    assert set(listed) == expected


def test_a_list_with_a_skin_for_every_point_has_every_pair_within_reach_once():
    """Skins from an eighth of the thickness to the thickness, at random: the pairs within h
    plus their skins, each once (the grid's cells looked at from each point and edge grow
    with the skins; an edge meets another from one of them only)."""
    from pipeline.physics import contact

    skins = np.random.default_rng(1).uniform(contact.SKIN_MIN, contact.SKIN_MAX, 400)
    listed, expected = _listed_against_brute_force(0.008, skins)
    assert len(listed) == len(set(listed))
    assert set(listed) == expected


# --- colliders ---------------------------------------------------------------------------

def test_the_list_leaves_out_the_neighbours_at_rest_and_learns_them():
    """A thickness of 0.76 of the fold's spacing: a point lies within it of the triangles
    across its cells' diagonals at rest. The list holds every pair within reach that is not
    within h at rest (brute force, the checker's distances), and the pairs it found within
    h at rest are learnt: each is such a pair (brute force), and a list made again with
    them, measuring them no more, is the same list."""
    from pipeline.physics import contact

    h = 0.012
    listed, expected = _listed_against_brute_force(h)
    assert len(listed) == len(set(listed))
    assert set(listed) == expected
    rest, x, tris = _folded_cloth(20, h, 0)
    n = x.shape[1]
    c = pack_contact(h, 0.3, tris, rest, np.ones(n), np.zeros(n, np.uint8))
    c = c._replace(listed=np.zeros((256 * n, 5), np.int64), listed_gap=np.zeros(256 * n))
    bare = contact.RobustContact(*c[:-1], None)
    contact._make_list(x, bare)
    first = c.listed[:c.count[0]].copy(), c.listed_gap[:c.count[0]].copy()
    counts = c.neighbour_count.copy()
    contact._make_list(x, bare)
    assert np.array_equal(c.neighbour_count, counts)  # none measured again, none learnt twice
    assert np.array_equal(c.listed[:c.count[0]], first[0])
    assert np.array_equal(c.listed_gap[:c.count[0]], first[1])
    at_rest = rest.T
    learnt = 0
    for p in range(n):
        for t in c.neighbours[p, :c.neighbour_count[p]]:
            a, b, d = tris[t]
            assert crossings.point_triangle_distance(*(at_rest[[v]] for v in (p, a, b, d)))[0] < h
            learnt += 1
    for e, (a, b) in enumerate(c.edges):
        for f in c.neighbours[n + e, :c.neighbour_count[n + e]]:
            u, v = c.edges[f]
            assert crossings.segment_segment_distance(
                *(at_rest[[w]] for w in (a, b, u, v)))[0] < h
            learnt += 1
    assert learnt > 300


def _fold_list(rows: int, threads: int):
    """The first candidate list of a 20 x 20 fold made in `rows` rows on `threads` numba
    threads: (its pairs and distances, or None where it did not fit; the contact)."""
    import numba

    from pipeline.physics import contact

    h = 0.008
    rest, x, tris = _folded_cloth(20, h, 0)
    n = x.shape[1]
    c = pack_contact(h, 0.3, tris, rest, np.ones(n), np.zeros(n, np.uint8))
    c = c._replace(listed=np.zeros((rows, 5), np.int64), listed_gap=np.zeros(rows))
    before = numba.get_num_threads()
    numba.set_num_threads(threads)
    try:
        contact._make_list(x, contact.RobustContact(*c[:-1], None))
    finally:
        numba.set_num_threads(before)
    count = c.count[0]
    if count > rows:
        return None, c
    return (c.listed[:count].copy(), c.listed_gap[:count].copy()), c


def test_the_list_made_on_the_threads_is_the_same_in_any_room_that_holds_it():
    """The list's queries run in runs on the threads, each into its own share of the rows:
    the same pairs in the same order on one thread and on two; where the rows hold the list
    but a run's share does not hold its pairs, the queries run again in one run (the same
    list); where the rows do not hold it, the count says so."""
    from pipeline.physics import contact

    (pairs, gaps), c = _fold_list(256 * 400, 1)
    count = len(pairs)
    assert count > 1000
    again, _ = _fold_list(256 * 400, 2)
    assert np.array_equal(again[0], pairs) and np.array_equal(again[1], gaps)
    tight, c = _fold_list(count, 2)
    # the edge pass's shares: the rows after the point-triangle pairs, split evenly
    share = (count - int(np.sum(pairs[:, 4] == 0))) // contact.CHUNKS
    assert c.found.max() > share  # a run did not fit its share
    assert np.array_equal(tight[0], pairs) and np.array_equal(tight[1], gaps)
    short, c = _fold_list(count - 1, 2)
    assert short is None and c.count[0] == count


def _collider_checker():
    spec = importlib.util.spec_from_file_location(
        "collider_crossings",
        Path(__file__).resolve().parents[1] / "benchmarks" / "collider_crossings.py")
    module = importlib.util.module_from_spec(spec)
    sys.modules.setdefault("collider_crossings", module)
    spec.loader.exec_module(module)
    return module


CC = _collider_checker()
NO_EDGES = np.zeros((0, 2), np.int64)


def _cloth(n: int, pinned=None) -> dict:
    cloth = {"width": 1, "height": 1, "num_width_points": n, "num_height_points": n,
             "orientation": 0, "thickness": 0.01, "damping": 0.2, "density": 150.0,
             "ks": 5000.0, "enable_structural": True, "enable_shearing": True,
             "enable_bending": True}  # horizontal at y = 1
    if pinned is not None:
        cloth["pinned"] = pinned
    return cloth


def projectile_scene(contact: str, kind: str) -> dict:
    """A cloth hanging from two corners, shot through from below at 600 m/s (22 cm a step)
    by a sphere of radius 4 cm or a turning box of half side 4 cm: one step per frame."""
    keys = [{"time": 0.02, "translation": [0, 0, 0], "rotation": [0, 0, 0]},
            {"time": 0.02 + 2.0 / 600.0, "translation": [0, 2.0, 0], "rotation": [0, 90, 30]}]
    if kind == "sphere":
        collider = {"sphere": {"origin": [0.5, 0.0, 0.5], "radius": 0.04, "friction": 0.3,
                               "keyframes": keys}}
    else:
        collider = {"box": {"center": [0.5, 0.0, 0.5], "half_extents": [0.04, 0.04, 0.04],
                            "rotation": [20, 0, 10], "friction": 0.3, "keyframes": keys}}
    return {"cloth": _cloth(20, [[0, 0], [19, 0]]), **collider,
            "simulation": {"frames_per_sec": 2700, "steps_per_frame": 1, "contact": contact}}


def _static(obj):
    return dataclasses.replace(obj, keyframes=type(obj.keyframes)())


def _to_rest(obj, points: np.ndarray, t: float) -> np.ndarray:
    """(N, 3) world points in the collider's rest frame at time t."""
    r, shift = CC.pose(obj, t)
    pivot = np.asarray(obj.pivot, float)
    return (points - pivot - shift) @ r + pivot


def violations(scene: dict, steps: int = 90):
    """(inside, edges through, paths through) summed over every step (one step a frame) of
    a scene with one collider, and the Simulation."""
    sim = Simulation(scene)
    obj = sim.scene.colliders[0]
    edges = CC.unique_edges(sim.model.triangles)
    n = sim.model.x0.shape[1]
    paths = np.stack([np.arange(n), np.arange(n) + n], axis=1)
    free = sim.model.pinned == 0
    inside = through = crossed = 0
    before, t0 = sim.positions.copy(), sim.time
    for _ in range(steps):
        sim.advance(1)
        now, t1 = sim.positions, sim.time
        v = CC.collider_violations(now, edges, [obj], t1, sim.model.pinned)
        inside += v["inside"]
        through += v["edges"]
        # each free point's path over the step, in the rest frame
        ends = np.concatenate([_to_rest(obj, before, t0), _to_rest(obj, now, t1)])
        p = CC.collider_violations(ends, paths[free], [_static(obj)], 0.0)
        crossed += p["edges"]
        before, t0 = now.copy(), t1
    return (inside, through, crossed), sim


@pytest.mark.parametrize("kind", ["sphere", "box"])
def test_a_projectile_never_passes_through_the_cloth_under_robust_contact(kind):
    course, _ = violations(projectile_scene("course", kind))
    assert sum(course) > 0, course  # the course's projection lets it through
    robust, sim = violations(projectile_scene("robust", kind))
    assert robust == (0, 0, 0)
    # it carried the cloth: points hit are now well above where the cloth hangs
    assert sim.positions[:, 1].max() > 1.1
    line = contact_summary(sim.system.contact, 1)
    assert "paths stopped at a surface" in line and "pinned point" not in line


def drape_scene(contact: str, collider: dict) -> dict:
    return {"cloth": _cloth(8), **collider,
            "simulation": {"contact": contact, "steps_per_frame": 30}}


SMALL_SPHERE = {"sphere": {"origin": [0.5, 0.6, 0.5], "radius": 0.09, "friction": 0.5}}
CORNER_UP = {"box": {"center": [0.5, 0.5, 0.5], "half_extents": [0.1, 0.1, 0.1],
                     "rotation": [45, 0, 35.264], "friction": 0.5}}


def _drape_counts(collider: dict) -> tuple[dict, Simulation]:
    """(points inside, edges through) of every frame of 45, by the independent checker,
    under each contact mode (drape_scene over `collider`); and the robust run."""
    counts = {}
    for contact in ("course", "robust"):
        sim = Simulation(drape_scene(contact, collider))
        edges = CC.unique_edges(sim.model.triangles)
        found = []
        for _ in range(45):
            sim.advance(1)
            v = CC.collider_violations(sim.positions, edges, sim.scene.colliders, sim.time)
            found.append((v["inside"], v["edges"]))
        counts[contact] = found
    return counts, sim


@pytest.mark.parametrize("collider", [SMALL_SPHERE, CORNER_UP], ids=["sphere", "box corner"])
def test_a_coarse_cloth_draped_on_a_small_collider_keeps_every_edge_out(collider):
    """Cells of 14 cm over a sphere of radius 9 cm, or a box standing on a corner: the
    course keeps the points out but its edges cut through; robust contact keeps both out."""
    counts, _ = _drape_counts(collider)
    assert max(e for _, e in counts["course"]) > 0
    assert all(f == (0, 0) for f in counts["robust"]), counts["robust"]


def test_a_pinned_point_inside_a_collider_is_named_with_its_frame():
    scene = {"cloth": _cloth(8, [[0, 0], [7, 0]]),
             "sphere": {"origin": [0.0, 1.0, 0.0], "radius": 0.05, "friction": 0.5},
             "simulation": {"contact": "robust"}}
    sim = Simulation(scene)
    sim.advance(3)
    line = contact_summary(sim.system.contact, sim.system.steps_per_frame)
    assert "pinned point 0 is inside a collider from frame 1" in line


def test_robust_colliders_are_deterministic():
    runs = []
    for _ in range(2):
        sim = Simulation(projectile_scene("robust", "box"))
        sim.advance(80)
        runs.append(sim.positions.tobytes())
    assert runs[0] == runs[1]


@pytest.mark.parametrize("contact", ["course", "robust"])
def test_a_sphere_rising_at_10_m_s_carries_the_cloth_lying_on_it(contact):
    """A free cloth settles on a sphere that then rises at 10 m/s: the cloth goes up with
    it (the guard allows a point twice a surface's speed: a bounce), and under robust
    contact no point and no edge is ever in the sphere."""
    scene = {"cloth": {**_cloth(20), "width": 0.8, "height": 0.8},
             "sphere": {"origin": [0.4, 0.65, 0.4], "radius": 0.25, "friction": 0.5,
                        "keyframes": [{"time": 0.4}, {"time": 0.55, "translation": [0, 1.5, 0]}]},
             "simulation": {"contact": contact}}
    sim = Simulation(scene)
    edges = CC.unique_edges(sim.model.triangles)
    worst = 0
    for _ in range(54):  # to 0.6 s
        sim.advance(1)
        v = CC.collider_violations(sim.positions, edges, sim.scene.colliders, sim.time)
        worst = max(worst, v["inside"] + v["edges"])
    assert np.median(sim.positions[:, 1]) > 2.0  # carried up with the sphere (top at 2.4 m)
    if contact == "robust":
        assert worst == 0


# --- mesh colliders (pipeline.physics.mesh_contact) ----------------------------------------

ICOSPHERE = str(Path(__file__).resolve().parents[1] / "scenes" / "meshes" / "icosphere5k.obj")


def write_cube(tmp_path: Path, side: float = 0.2) -> str:
    import trimesh

    path = tmp_path / "cube.obj"
    trimesh.creation.box(extents=(side, side, side)).export(path)
    return str(path)


def write_sheet(tmp_path: Path, side: float = 0.5) -> str:
    """A one-sided square of two triangles in the plane y = 0, centred on the origin."""
    h = side / 2
    path = tmp_path / "sheet.obj"
    path.write_text(f"v {-h} 0 {-h}\nv {h} 0 {-h}\nv {h} 0 {h}\nv {-h} 0 {h}\nf 1 3 2\nf 1 4 3\n")
    return str(path)


@pytest.mark.parametrize("shape", ["box corner", "icosphere"])
def test_a_coarse_cloth_dropped_on_a_small_solid_mesh_keeps_every_edge_out(shape, tmp_path):
    """A mesh cube standing on a corner, or an icosphere of radius 9 cm, under cells of 14 cm:
    the course's level set keeps the points out but edges cut through; robust contact keeps
    both out at every frame (the independent checker)."""
    if shape == "box corner":
        mesh = {"path": write_cube(tmp_path), "translation": [0.5, 0.5, 0.5],
                "rotation": [45, 0, 35.264]}
    else:
        mesh = {"path": ICOSPHERE, "translation": [0.5, 0.6, 0.5], "scale": 0.09}
    collider = {"mesh": {**mesh, "friction": 0.5, "thickness": 0.005}}
    counts, sim = _drape_counts(collider)
    assert max(e for _, e in counts["course"]) > 0
    assert all(f == (0, 0) for f in counts["robust"]), counts["robust"]
    assert sim.system.contact.stats[FACE_PUSHES] > 0  # it pushed edges out


def sweep_scene(contact: str, path: str) -> dict:
    """A cloth hanging from two corners, swept up through by a keyframed mesh cube of side
    0.2 m rising 1 m and turning in 0.1 s (10 m/s): one step a frame."""
    keys = [{"time": 0.05}, {"time": 0.15, "translation": [0, 1.0, 0], "rotation": [0, 90, 30]}]
    return {"cloth": _cloth(16, [[0, 0], [15, 0]]),
            "mesh": {"path": path, "translation": [0.5, 0.6, 0.5], "rotation": [20, 0, 10],
                     "friction": 0.3, "thickness": 0.005, "keyframes": keys},
            "simulation": {"frames_per_sec": 200, "steps_per_frame": 1, "contact": contact}}


def test_a_keyframed_mesh_swept_through_a_hanging_cloth_carries_it(tmp_path):
    cube = write_cube(tmp_path)
    course, _ = violations(sweep_scene("course", cube), 40)
    assert min(course) > 0, course  # points inside, edges through and paths through
    robust, sim = violations(sweep_scene("robust", cube), 40)
    assert robust == (0, 0, 0)
    assert sim.positions[:, 1].max() > 1.3  # carried up on the cube
    assert "pinned point" not in contact_summary(sim.system.contact, 1)


def test_a_cloth_sliding_off_a_one_sided_sheet_never_passes_through_it(tmp_path):
    """A 0.4 m cloth falls onto a one-sided square sheet turned 30 degrees, without friction,
    and slides off its lower rim: under the course's handling its edges pass through the
    sheet; under robust contact no edge and no point's path ever does, and going round the
    rim is not counted as a crossing."""
    def scene(contact: str) -> dict:
        cloth = {**_cloth(10), "width": 0.4, "height": 0.4}
        return {"cloth": cloth,
                "mesh": {"path": write_sheet(tmp_path), "translation": [0.2, 0.8, 0.2],
                         "rotation": [0, 0, 30], "solid": False, "friction": 0.0,
                         "thickness": 0.005},
                "simulation": {"frames_per_sec": 300, "steps_per_frame": 1, "contact": contact}}

    course, _ = violations(scene("course"), 200)
    assert course[1] > 0, course
    robust, sim = violations(scene("robust"), 200)
    assert robust == (0, 0, 0)
    lower_rim = 0.2 - 0.25 * np.cos(np.radians(30))
    assert sim.positions[:, 0].max() < lower_rim and sim.positions[:, 1].max() < 0.5  # off it


def test_points_inside_a_solid_mesh_go_out_to_its_nearest_surface(tmp_path):
    """mesh_contact's pass on its own: free points inside a mesh cube (still, from inside)
    end SURFACE_GAP outside its nearest face; a pinned one is named."""
    from pipeline.physics.collider_contact import SURFACE_GAP
    from pipeline.physics.colliders import pack_colliders
    from pipeline.physics.mesh_contact import mesh_colliders, pack_meshes
    from pipeline.scene import MeshCollider

    obj = MeshCollider(path=Path(write_cube(tmp_path)), friction=0.0)
    table = pack_colliders([obj], 7)
    x = np.ascontiguousarray(np.array([[0.05, 0.0, 0.0], [0.0, -0.08, 0.01], [0.3, 0.0, 0.0],
                                       [0.0, 0.09, 0.0], [2, 0, 0], [3, 0, 0], [2, 0, 1]]).T)
    x0 = x.copy()  # points 0-3 on no triangle (no edge pushes)
    c = pack_contact(0.01, 0.0, np.array([[4, 5, 6]]), x, np.ones(7),
                     np.array([0, 0, 0, 1, 0, 0, 0], np.uint8), self_on=False,
                     meshes=pack_meshes([obj], 7))
    mesh_colliders(x, x0, c.meshes, c.edges, c.inv_mass, c.stats, table.params, table.data,
                   table.key_count, table.pivot, table.pose, 0, c.solid_stage, c.sheet_stage)
    assert np.allclose(x[:, 0], [0.1 + SURFACE_GAP, 0, 0]) and np.allclose(
        x[:, 1], [0, -0.1 - SURFACE_GAP, 0.01])
    assert np.array_equal(x[:, 2:], x0[:, 2:])  # outside, and pinned
    assert c.stats[MOVED_OUT] == 2 and c.stats[PIN_POINT] == 3
    v = CC.collider_violations(x.T, NO_EDGES, [obj], 0.0, np.array([3]))
    assert v["inside"] == 0


def _pulled_strip(tmp_path, contact: str) -> dict:
    """A horizontal 1 m x 0.1 m mesh strip of 11 x 2 points, its left end held still and its
    right end carried away along the strip at 0.35 m/s (60 fps)."""
    from test_mesh_cloth import horizontal_grid_obj, mesh_scene

    scene = mesh_scene(horizontal_grid_obj(tmp_path, 11, 2, 1.0, 0.1),
                       pinned=[0, 11, {"indices": [10, 21], "keyframes": [
                           {"time": 0.0}, {"time": 1.0, "translation": [0.35, 0.0, 0.0]}]}])
    scene["simulation"].update(contact=contact, frames_per_sec=60, steps_per_frame=10)
    return scene


def test_provots_limit_stops_where_the_pins_pull_beyond_its_reach(tmp_path, capsys):
    """Under the limit the strip's ends can be at most 1.1 x 1 m apart (ten springs of 0.1 m
    along a row). The pins pass 1.1 m at t = 0.1 / 0.35 = 0.2857 s, inside frame 18 (t_17
    = 0.2833 s): robust contact stops the limit from that frame and says which points; the
    course contact keeps it (its behaviour unchanged: the same positions until then, others
    after). Stepping frame by frame or in one call gives the same positions."""
    sim = Simulation(_pulled_strip(tmp_path, "robust"))
    course = Simulation(_pulled_strip(tmp_path, "course"))
    assert sim.limit_stop is None and sim.limit_watch is not None
    sim.advance(17)
    course.advance(17)
    assert sim.limit_stop is None and sim.system.stretch_limit
    # nothing else differs here (no self-collision, no collider): the same bits until the stop
    assert np.array_equal(sim.positions, course.positions)
    sim.advance(1)
    stop = sim.limit_stop
    assert stop.frame == 18 and stop.time == pytest.approx(0.3)
    assert stop.points == (0, 10)  # the first row's ends (the second row's are as far)
    assert stop.distance == pytest.approx(1.0 + 0.35 * 0.3, abs=1e-12)
    assert stop.reach == pytest.approx(1.1, abs=1e-12)
    assert not sim.system.stretch_limit and sim.limit_watch is None
    sim.advance(12)
    again = Simulation(_pulled_strip(tmp_path, "robust"))
    again.step(7)
    again.step(293)  # across the frame boundaries, unevenly
    assert np.array_equal(again.positions, sim.positions)
    assert again.limit_stop == stop
    course.advance(13)
    assert course.limit_watch is None and course.limit_stop is None
    assert course.system.stretch_limit
    assert not np.array_equal(sim.positions, course.positions)  # the limit still acts there

    from pipeline.cli import main

    scene = tmp_path / "strip.json"
    scene.write_text(json.dumps(_pulled_strip(tmp_path, "robust")))
    capsys.readouterr()
    assert main(["plan", str(scene)]) == 0
    assert ("stretch limit: Provot's, stopped if the keyframed pins pull two points beyond "
            "its reach" in capsys.readouterr().out)
    assert main([str(scene), "--duration", "0.4", "--out", str(tmp_path / "s.gif")]) == 0
    assert ("Provot's stretch limit stopped from frame 18: at t = 0.300 s the pins hold "
            "points 0 and 10 1.105 m apart, beyond the 1.1 m") in capsys.readouterr().err


def _stack(layers: int, gap: float, h: float):
    """`layers` large parallel triangles `gap` h apart, still, apart at rest (every pair is
    checked): (x0, x1, contact, triangles)."""
    points, rest, tris = [], [], []
    for k in range(layers):
        for x, z in ((-1.0, -1.0), (1.0, -1.0), (0.0, 1.0)):
            points.append((x, gap * h * k, z))
            rest.append((x + 3.0 * k, 0.0, z))
        tris.append((3 * k, 3 * k + 1, 3 * k + 2))
    x0 = np.ascontiguousarray(np.array(points).T)
    c = pack_contact(h, 0.0, np.array(tris), np.ascontiguousarray(np.array(rest).T),
                     np.ones(3 * layers), np.zeros(3 * layers, np.uint8))
    return x0, x0.copy(), c, tris


def test_layers_pressed_together_are_pushed_apart_in_more_rounds():
    """Four large parallel triangles 0.4 h apart, still: one round's pushes, averaged per
    point, leave the inner layers where their pairs above and below push them both ways
    (0.47 h from another layer after it); the rounds repeated in place while a pair is
    closer than 3/4 of the thickness leave every point 0.97 h from every other layer
    (averaged rounds: 0.73 h), the layers in their order."""
    from pipeline.physics.contact import PRESSED

    h, layers = 0.01, 4
    x0, x1, c, tris = _stack(layers, 0.4, h)
    robust_contact(x1, x0, c)
    # every point's distance to every other layer (the checker's), and the layers' order
    p = x1.T
    gaps = [crossings.point_triangle_distance(p[i][None], *(p[[j]] for j in tris[k]))[0] / h
            for i in range(3 * layers) for k in range(layers) if i // 3 != k]
    assert min(gaps) > 0.9 and c.stats[2] == 0  # without a CCD stop
    assert np.all(np.diff([p[3 * k:3 * k + 3, 1].mean() for k in range(layers)]) > 0)
    assert c.stats[PRESSED] == 0


def test_layers_the_rounds_cannot_part_are_reported():
    """Ten layers 0.1 h apart: the rounds run out with pairs still closer than half the
    thickness, and the summary says from which frame and what to do."""
    from pipeline.physics.contact import PRESSED, PRESSED_STEP

    x0, x1, c, _ = _stack(10, 0.1, 0.01)
    robust_contact(x1, x0, c)
    assert c.stats[PRESSED] == 1 and c.stats[PRESSED_STEP] == 1
    assert ("from frame 1, 1 steps ended with layers still pressed closer than 0.5 x "
            "thickness after 5 rounds of pushes") in contact_summary(c, 10)

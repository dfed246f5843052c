"""The first run on a machine (pipeline/run/warmup.py): an empty numba cache is filled by
render and its compile helper together, the output is the same as a warm run's, and the
next run finds every kernel cached."""
from __future__ import annotations

import io
import itertools
import json
import os
import pickle
import random
import re
import subprocess
import sys
import threading
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest

from conftest import SCENES, cloth_dict, scene_dict, scene_path

from pipeline.run import warmup
from pipeline import simulation
from pipeline.simulation import Simulation

#: the folder holding the package these tests import
HOME = Path(warmup.__file__).resolve().parents[2]
SCENE = scene_dict(cloth_dict(10, 10, thickness=0.0095, damping=0.2, density=150.0, ks=5000.0),
                   spheres=[((0.5, 0.2, 0.5), 0.2, 0.3)])


def _render(scene: Path, out: Path, cache: Path, cwd: Path) -> str:
    """`render` as an installed command runs it: the package these tests import (installed,
    or the tree), started in `cwd`."""
    env = {"PATH": "/usr/bin:/bin", "NUMBA_CACHE_DIR": str(cache)}
    code = f"import sys; sys.path.insert(0, {str(HOME)!r}); from pipeline.cli import main; " \
           "sys.exit(main())"
    r = subprocess.run([sys.executable, "-c", code, str(scene), "--out", str(out),
                        "--size", "24x24", "--duration", "0.2"], env=env, cwd=cwd,
                       capture_output=True, text=True, timeout=900)
    assert r.returncode == 0, r.stderr
    return r.stderr.strip().splitlines()[-1]


def test_cold_run_fills_the_cache_for_the_next_run(tmp_path):
    scene = tmp_path / "s.json"
    scene.write_text(json.dumps(SCENE))
    cache = tmp_path / "numba"
    # started in a folder holding another `pipeline` (a user's clone beside the installed
    # package): the compile helper must import the package render runs, not this one
    decoy = tmp_path / "work" / "pipeline"
    decoy.mkdir(parents=True)
    marker = tmp_path / "decoy-imported"
    (decoy / "__init__.py").write_text(f"open({str(marker)!r}, 'w').close()\n"
                                       "raise ImportError('the decoy package')\n")
    (decoy / "warmup.py").write_text("")
    cold = _render(scene, tmp_path / "cold.gif", cache, decoy.parent)
    assert not marker.exists(), "the compile helper imported the working folder's pipeline"
    assert re.search(r"; compile [\d.]+ s, simulate", cold), cold
    # the helper's share (forces, the renderer's fragment stage) and this process's share
    # (colliders) are all in the one cache
    names = {p.name.split("-")[0] for p in cache.rglob("*.nbi")}
    assert {"forces.internal_forces", "__init__.collide_all", "shade._fragment_stage",
            "verlet.advance"} <= names, sorted(names)
    warm = _render(scene, tmp_path / "warm.gif", cache, decoy.parent)
    assert "compile" not in warm, warm
    assert (tmp_path / "cold.gif").read_bytes() == (tmp_path / "warm.gif").read_bytes()


# the jobs a scene can have (warmup.sim_jobs): these always, a model's, a collider table's
# (a mesh's projection and sweep, or the projection's stand-in, and the sweeps of its other
# kinds), wind or not, self-collision or not
COMMON = ["pipeline.physics.colliders:collide_all", "pipeline.physics.colliders:_collide_range",
          "pipeline.physics.system:motion_summary", "pipeline.physics.system:energy_guard",
          "pipeline.physics.reach:reach_check"]
MODELS = [["pipeline.physics.forces:internal_forces", "pipeline.physics.forces:_direction_forces",
           "pipeline.physics.forces:_gather", "pipeline.physics.constraints:limit_stretch",
           "pipeline.physics.constraints:_flag_long", "pipeline.physics.constraints:_pack_mask"],
          ["pipeline.physics.forces:fem_internal_forces", "pipeline.physics.fem:_triangles",
           "pipeline.physics.fem:_hinges", "pipeline.physics.fem:_bands_of_parity",
           "pipeline.physics.fem:fem_filtered_jacobian_product"]]
SWEEPS = ["pipeline.physics.colliders:sweep_sphere", "pipeline.physics.colliders:sweep_plane",
          "pipeline.physics.colliders:sweep_box"]
MESH = ["pipeline.physics.colliders.mesh:project", "pipeline.physics.colliders:sweep_mesh"]
POSES = ["pipeline.physics.colliders:update_poses"]  # a table with keyframes
# two tables for the split test: a keyframed mesh and a plane, a sphere (the README's)
TABLES = [MESH + [SWEEPS[1]] + POSES, ["pipeline.physics.colliders:_unmoved", SWEEPS[0]]]
# every table: a mesh or not, any of the other kinds, keyframes or not
ALL_TABLES = [base + list(kinds) + poses
              for base in (MESH, ["pipeline.physics.colliders:_unmoved"]) for poses in ([], POSES)
              for r in range(len(SWEEPS) + 1) for kinds in itertools.combinations(SWEEPS, r)]
# the loops over the points through the colliders and of Provot's pre-pass (the classic
# model's): serial for the course's sizes, parallel from forces.PARALLEL_POINTS points on
LOOPS = [(["pipeline.physics.colliders:_collide_serially"], ["pipeline.physics.constraints:_mark_serially"]),
         (["pipeline.physics.colliders:_collide_in_chunks"], ["pipeline.physics.constraints:_mark_in_chunks"])]
WINDS = [[], ["pipeline.physics.wind:add_wind_force", "pipeline.physics.wind:_band"]]
ROBUST = ["pipeline.physics.contact:robust_contact",
          "pipeline.physics.collider_contact:robust_colliders"]
# robust contact's stage 2 for a sphere or a box (absent for a plane)
SOLID_FACES = "pipeline.physics.collider_contact:solid_faces"
# robust contact's colliders with a solid or a one-sided mesh (a horizontal cloth: no
# self-contact, no pair visits): the meshes' pass and that kind's stages
ROBUST_MESH = ROBUST + ["pipeline.physics.mesh_contact:mesh_colliders"]
# the course's self-collision: its boxes pushed serially, or on the threads from
# self_collision.PARALLEL_POINTS points on (selfCollision's 2500); robust self-contact: the
# pair visits and the check for a cloth that starts crossing itself
SELF = [[], ["pipeline.physics.self_collision:self_collide",
             "pipeline.physics.self_collision:_push_members"],
        ["pipeline.physics.self_collision:self_collide_in_chunks",
         "pipeline.physics.self_collision:_push_members"],
        ROBUST + ["pipeline.physics.contact:_visit", "pipeline.physics.contact:_tangles"],
        ROBUST + ["pipeline.physics.contact:_visit", "pipeline.physics.contact:_tangles",
                  SOLID_FACES],
        ROBUST + [SOLID_FACES],
        ROBUST_MESH + ["pipeline.physics.mesh_contact:solid_stage"],
        ROBUST_MESH + ["pipeline.physics.mesh_contact:sheet_stage"]]
IMPLICIT = ["pipeline.physics.integrators.implicit_euler:solve_step",
            "pipeline.physics.integrators.implicit_euler:_update"]
# VBD's: one descent over flat element lists for every model and cloth, its colours' loop
# serial below vbd.PARALLEL_POINTS points and parallel from there (pinned2's 2601)
VBD = ["pipeline.physics.integrators.vbd:_predict", "pipeline.physics.integrators.vbd:_sweep",
       "pipeline.physics.integrators.vbd:_velocities"]
VBD_SERIAL = VBD + ["pipeline.physics.integrators.vbd:descend"]
VBD_PARALLEL = VBD + ["pipeline.physics.integrators.vbd:descend_in_chunks"]
# the kernels each integrator's State points to, with the classic model and with the FEM
STATE_KERNELS = {
    "implicit-euler": (IMPLICIT + ["pipeline.physics.forces:spring_prepare",
                                   "pipeline.physics.forces:spring_product",
                                   "pipeline.physics.forces:_jacobian_pass",
                                   "pipeline.physics.forces:spring_diagonal"],
                       IMPLICIT + ["pipeline.physics.forces:fem_prepare", "pipeline.physics.forces:fem_product",
                                   "pipeline.physics.forces:fem_diagonal"]),
    "verlet": (["pipeline.physics.integrators.verlet:_update_all"],) * 2,
    "euler": (["pipeline.physics.integrators.euler:euler_update"],) * 2,
    "symplectic-euler": (["pipeline.physics.integrators.euler:euler_update"],) * 2,
    "rk4": (["pipeline.physics.integrators.rk4:_stage", "pipeline.physics.integrators.rk4:_finish"],) * 2,
    "xpbd": (["pipeline.physics.integrators.xpbd:solve_springs"], ["pipeline.physics.integrators.xpbd:solve_fem"]),
    "vbd": (VBD_PARALLEL, VBD_PARALLEL)}
# (and none: the integrator's kernels cached)
INTEGRATORS = [([], [])] + [kernels for name, kernels in STATE_KERNELS.items()
                            if name != "symplectic-euler"] + [(VBD_SERIAL, VBD_SERIAL)]
# called by the stepping kernel directly, not through a pointer
LINKED = {"pipeline.physics.system:motion_summary", "pipeline.physics.system:energy_guard"}
# a mesh cloth's (cloth.mesh): its forces (classic with Provot's limit, or the FEM; the
# stability limit's forces compiled with them), its wind, and the integrators that step it
MESH_MODELS = [["pipeline.physics.mesh_forces:mesh_internal_forces",
                "pipeline.physics.mesh_forces:mesh_limit_stretch"],
               ["pipeline.physics.mesh_forces:mesh_fem_internal_forces"]]
MESH_WINDS = [[], ["pipeline.physics.mesh_wind:add_mesh_wind_force"]]
MESH_INTEGRATORS = [([], [])] + [STATE_KERNELS[name] for name in ("verlet", "euler", "rk4")] + [
    (IMPLICIT + ["pipeline.physics.mesh_forces:mesh_spring_prepare",
                 "pipeline.physics.mesh_forces:mesh_spring_apply",
                 "pipeline.physics.mesh_forces:mesh_spring_diagonal"],
     IMPLICIT + ["pipeline.physics.mesh_forces:mesh_fem_prepare",
                 "pipeline.physics.mesh_forces:mesh_fem_apply",
                 "pipeline.physics.mesh_forces:mesh_fem_diagonal"]),
    (["pipeline.physics.mesh_xpbd:solve_mesh_springs"],
     ["pipeline.physics.mesh_xpbd:solve_mesh_fem"]),
    (VBD_SERIAL, VBD_SERIAL)]


def _scenes(tables=TABLES, loops=LOOPS[:1]) -> list[list[str]]:
    return [COMMON + m + t + p[0] + (p[1] if k == 0 else []) + w + c + i[k]
            for (k, m), t, p, w, c, i in
            itertools.product(enumerate(MODELS), tables, loops, WINDS, SELF, INTEGRATORS)]


def _mesh_scenes(tables=TABLES, loops=LOOPS[:1]) -> list[list[str]]:
    """The same for a mesh cloth (no Provot pre-pass: its limit is one serial kernel)."""
    return [COMMON + m + t + p[0] + w + c + i[k]
            for (k, m), t, p, w, c, i in
            itertools.product(enumerate(MESH_MODELS), tables, loops, MESH_WINDS, SELF,
                              MESH_INTEGRATORS)]


def _mesh_variants(tmp_path) -> list[tuple[Path, list[str]]]:
    """Mesh-cloth scenes of every kind of job: classic and FEM, with wind and
    self-collision, and with a keyframed mesh collider."""
    from test_mesh_cloth import horizontal_grid_obj, mesh_scene

    path = tmp_path / "mesh.json"
    path.write_text(json.dumps(mesh_scene(horizontal_grid_obj(tmp_path, 6, 6), pinned=(0, 5))))
    wind = 'wind={"velocity": [3.0, 0.0, 1.0], "gust": 1.0}'
    bowl = ('mesh={"path": "%s", "scale": 0.3, "translation": [0.5, 0.5, 0.5], '
            '"friction": 0.3, "keyframes": [{"time": 0}, {"time": 1, "translation": [0, 0.1, 0]}]}'
            % (SCENES / "meshes" / "bowl.obj"))
    return [(path, [f'simulation.model="{model}"'] + extra) for model in ("classic", "fem")
            for extra in ([], [wind, "simulation.self_collision=true"], [bowl])]


def _jobs(names) -> list[warmup.Job]:
    return sorted((warmup.Job(n, (), n in LINKED) for n in sorted(names)),
                  key=lambda j: -warmup.COMPILE_SECONDS[j.name])


@pytest.mark.filterwarnings("ignore::pipeline.physics.overlap.StartInsideWarning")  # scenes that mean it
def test_every_job_of_a_scene_has_an_estimate(tmp_path):
    """The scenes above are the estimates' kernels, and every kernel a scene of scenes/
    (and a mesh cloth of each kind) compiles with any integrator that steps it is among
    them (start needs its estimate: without one the first run would compile everything
    on first use, in one process)."""
    from pipeline.scene import INTEGRATORS, load_scene
    from pipeline.simulation import cloth_model
    from pipeline.physics.system import build_system

    every = [set(listed) for listed in _scenes(ALL_TABLES, LOOPS)
             + _mesh_scenes(ALL_TABLES, LOOPS)]
    assert set().union(*every) == set(warmup.COMPILE_SECONDS)
    assert set(warmup.STEP_SECONDS) == set(INTEGRATORS)  # every stepping kernel's estimate
    seen = set()
    larger = ["cloth.num_width_points=80", "cloth.num_height_points=80"]  # the parallel loop
    for path, overrides in [(p, []) for p in sorted(SCENES.glob("*.json"))] + [
            (SCENES / "sphere.json", larger),
            (SCENES / "selfCollision.json", ["simulation.contact=robust"]),
            (SCENES / "sphere.json", ["simulation.contact=robust"]),  # a solid's faces
            (SCENES / "sphere.json", ["simulation.contact=robust",
                                      "simulation.self_collision=true"]),
            (SCENES / "bowl.json", ["simulation.contact=robust"]),  # a solid mesh collider
            (SCENES / "bowl.json", ["simulation.contact=robust", "mesh.solid=false"])
    ] + _mesh_variants(tmp_path):
        scene = load_scene(path, overrides)
        system = build_system(scene, cloth_model(scene))
        names = {job.name for job in warmup.sim_jobs(system)}
        assert {job.name for job in warmup.sim_jobs(system) if job.linked} <= LINKED
        assert names in every, (path.name, overrides)  # a combination above
        for integrator in INTEGRATORS:
            names |= {job.name for job in warmup.integrator_jobs(integrator, system)[1]}
        assert names <= set(warmup.COMPILE_SECONDS), path.name
        seen |= names
    # the FEM's kernels, a mesh's projection, every collider kind, keyframes, wind,
    # self-collision and both loops over the points all occur
    assert seen == set(warmup.COMPILE_SECONDS)


def test_an_integrators_jobs_are_its_own_present_kernels():
    """Each integrator's jobs on pinned2 with either model are exactly its kernels above: not
    the kernels sim_jobs has already (implicit Euler's product calls the forces' gather),
    nor the absent pointers of the other model (the springs' product passes, with the FEM)."""
    from pipeline.scene import INTEGRATORS as NAMES, load_scene
    from pipeline.simulation import cloth_model
    from pipeline.physics.system import build_system

    assert set(STATE_KERNELS) == set(NAMES)
    for k, model in enumerate(("classic", "fem")):
        scene = load_scene(scene_path("pinned2"), overrides=[f'simulation.model="{model}"'])
        system = build_system(scene, cloth_model(scene))
        for name in NAMES:
            jobs = warmup.integrator_jobs(name, system)[1]
            assert sorted(job.name for job in jobs) == sorted(STATE_KERNELS[name][k]), (model,
                                                                                       name)


def test_one_stepping_kernel_serves_both_models_wind_self_collision_and_both():
    """Every integrator's stepping kernel is typed (compiled) the same for the classic
    model and the FEM (each model's kernels go through pointers, the other's absent) and
    for a cloth with wind, self-collision or both (their passes go through pointers, absent
    when off): a scene with one after a scene with the other compiles that model's or
    pass's kernels only, not the stepping kernel again. A cloth with neither wind nor
    self-collision keeps both None (numba prunes them: the README scene's lean kernel), of
    either model. The passes are compiled (jobs) only where the scene has them."""
    from pipeline.scene import INTEGRATORS, load_scene
    from pipeline.simulation import cloth_model
    from pipeline.physics.system import build_system
    from clothjit import argument_types

    wind = 'wind={"velocity": [3.0, 0.0, 1.0], "gust": 1.0}'
    self_on = "simulation.self_collision=true"
    systems = {}
    for model in ("classic", "fem"):
        base = ["simulation.self_collision=false", f'simulation.model="{model}"']
        for extra in ([], [wind], [self_on], [wind, self_on]):
            scene = load_scene(scene_path("pinned2"), overrides=base + extra)
            systems[model, tuple(extra)] = build_system(scene, cloth_model(scene))
    for (model, extra), system in systems.items():
        assert system.classic == (model == "classic")
        names = {job.name for job in warmup.sim_jobs(system)}
        assert ("pipeline.physics.wind:add_wind_force" in names) == (wind in extra)
        assert ("pipeline.physics.wind:_band" in names) == (wind in extra)
        assert ("pipeline.physics.self_collision:self_collide_in_chunks" in names) == (
            self_on in extra)  # pinned2's 2500 points
        assert ("pipeline.physics.self_collision:_push_members" in names) == (self_on in extra)
        assert ("pipeline.physics.fem:_triangles" in names) == (model == "fem")
        assert ("pipeline.physics.constraints:limit_stretch" in names) == (model == "classic")
        if not extra:
            assert system.wind is None and system.scratch is None
    for integrator in INTEGRATORS:
        for lean in (True, False):
            kinds = set()
            for (model, extra), system in systems.items():
                if (not extra) == lean:
                    job = warmup.integrator_jobs(integrator, system)[0]
                    kinds.add(argument_types(job.dispatcher(), job.args))
            assert len(kinds) == 1, (integrator, lean)


def test_prepare_comes_before_the_stability_limit(monkeypatch):
    """Simulation(prepare=...) hands the model and System to the warm-up before the
    stability limit runs (a FEM cloth's runs the element kernels)."""

    calls = []
    limit = simulation.stability_limit
    monkeypatch.setattr(simulation, "stability_limit",
                        lambda model: calls.append("limit") or limit(model))
    sim = Simulation(SCENE, prepare=lambda model, system: calls.append(
        (model, system)))
    assert len(calls) == 2 and calls[1] == "limit"
    assert calls[0][0] is sim.model and calls[0][1] is sim.system


def _here_sums(free) -> np.ndarray:
    """The compile seconds each way of sharing the `free` jobs keeps here, for all 2^k ways
    (way w keeps job i here if its bit i is set), by doubling: the ways without job i, then
    the same ways with it."""
    sums = np.zeros(1)
    for job in free:
        sums = np.concatenate([sums, sums + warmup.COMPILE_SECONDS[job.name]])
    return sums


def _best_splits(linked, free, here_sums, render, step, rng) -> float:
    """The best estimate of every way of sharing the `free` jobs (`linked` stay here), from
    their sums here (`_here_sums`), each way's estimate checked against
    warmup.estimate_seconds where k <= 4, else on the best way and four random ones."""
    total = sum(warmup.COMPILE_SECONDS[j.name] for j in free)
    mine = sum(warmup.COMPILE_SECONDS[j.name] for j in linked) + here_sums
    theirs = total - here_sums
    rendering = warmup.RENDER_SECONDS if render else 0.0
    ways = warmup.CONTENTION * np.maximum(mine + step,
                                          warmup.HELPER_START + theirs + rendering)
    checked = (range(len(ways)) if len(free) <= 4 else
               [int(np.argmin(ways))] + [rng.randrange(len(ways)) for _ in range(4)])
    for side in checked:
        estimate = warmup.estimate_seconds(
            linked + [j for k, j in enumerate(free) if side >> k & 1],
            [j for k, j in enumerate(free) if not side >> k & 1], render, step, True)
        assert abs(estimate - ways[side]) <= 1e-9, (estimate, ways[side])
    return float(ways.min())


EXHAUSTIVE = 16  # free kernels; beyond, 2^k ways cost seconds per part


def test_split_balances_the_two_processes():
    """On every scene's kernels, all cold and 12 random parts of them (the rest cached):
    the split is within 4/3 of the best one (every way of sharing them, the linked callees
    here; searched where at most EXHAUSTIVE kernels are free: 2^k ways) and beats one
    process when it starts the helper."""
    rng, checks = random.Random(15), random.Random(16)
    for names in _scenes() + _mesh_scenes()[::5]:
        parts = [names] + [[n for n in names if rng.random() < 0.5] for _ in range(12)]
        for part in filter(None, parts):
            jobs = _jobs(part)
            free = [j for j in jobs if not j.linked]
            linked = [j for j in jobs if j.linked]
            here_sums = _here_sums(free) if len(free) <= EXHAUSTIVE else None
            for render in (False, True):
                for step in (0.0, min(warmup.STEP_SECONDS.values()),
                             max(warmup.STEP_SECONDS.values())):
                    here, helper, two = warmup.split(jobs, render, step)
                    assert sorted(j.name for j in here + helper) == sorted(part)
                    assert not any(j.linked for j in helper)
                    alone = warmup.estimate_seconds(jobs, [], render, step, False)
                    chosen = warmup.estimate_seconds(here, helper, render, step, two)
                    # the helper only when it is faster than one process
                    assert chosen <= alone and (two or not helper)
                    if here_sums is None:
                        continue
                    # longest first to the side that ends sooner: near the best split
                    best = _best_splits(linked, free, here_sums, render, step, checks)
                    assert chosen <= min(alone, best * 4 / 3) + 1e-9
    # the README scene: the renderer and every simulation kernel cold -> two processes
    readme = _jobs(COMMON + MODELS[0] + TABLES[1])
    assert warmup.split(readme, True, warmup.STEP_SECONDS["verlet"])[2]
    # one small kernel and nothing else: compiled here
    small = [warmup.Job("pipeline.physics.system:energy_guard", (), True)]
    assert warmup.split(small, False, 0.0) == (small, [], False)


class _Counted:
    """A stand-in for the progress bar: its total and the updates it got."""

    def __init__(self, total, *args):
        self.total, self.done = total, 0

    def update(self, n):
        self.done += n

    def close(self):
        pass


class _Job(warmup.Job):
    def __init__(self, name, cached=False):
        super().__init__(name, ())
        self.is_cached, self.compiled = cached, 0

    def cached(self):
        return self.is_cached

    def compile(self):
        self.compiled += 1
        self.is_cached = True


class _Helper:
    """A stand-in for the compile helper's process: it reports one kernel, then the end of
    its simulation share."""

    def __init__(self, *args, **kwargs):
        self.stdin = io.BytesIO()
        self.stdout = io.BytesIO(b"b\n" + warmup.SIMULATION_DONE + b"\n")

    def wait(self):
        return 0

    def kill(self):
        pass


@pytest.mark.parametrize("step", [False, True])
def test_the_bar_counts_each_kernel_compiled_once(monkeypatch, step):
    """The bar's total is what gets compiled, in two processes too: the stepping kernel
    counts only when it is not cached, and is compiled once, in start."""
    bars = []
    stepping = _Job("pipeline.physics.integrators.verlet:advance", cached=not step)
    monkeypatch.setattr(warmup, "bar", lambda *a: bars.append(_Counted(*a)) or bars[-1])
    monkeypatch.setattr(warmup, "sim_jobs", lambda system: [
        _Job("pipeline.physics.reach:reach_check"), _Job("pipeline.physics.system:energy_guard")])
    monkeypatch.setattr(warmup, "integrator_jobs", lambda integrator, system: (stepping, []))
    monkeypatch.setattr(warmup, "split", lambda jobs, render, step: (jobs[:1], jobs[1:], True))
    monkeypatch.setattr(warmup.subprocess, "Popen", _Helper)
    with warmup.FirstRun("verlet") as first:
        first.start(None, None)
        first.finish(SimpleNamespace(integrator="verlet", system=None))
    assert bars[0].total == 2 + step and bars[0].done == bars[0].total
    assert stepping.compiled == step


def _fresh_kernels():
    """Two kernels numba has not compiled (not cached: compiled in the test whatever
    numba's cache holds), outer calling inner."""
    from numba import njit

    @njit
    def inner(a):
        return max(a, 0.5) * 2.0  # max: numba compiles its own overload too (not counted)

    @njit
    def outer(a):
        return inner(a) + 1.0

    return outer


def test_compiles_outside_the_warm_up_are_said_counted_and_timed(monkeypatch):
    """A compile while the Simulation is built and before start (a mesh collider's
    distance grid) says the first-run message once, counts each kernel (callee included)
    and is timed; kernels already compiled say and count nothing."""
    outer = _fresh_kernels()
    said = []
    counted = _Counted(None)
    monkeypatch.setattr(warmup, "counter", lambda *a: counted)
    monkeypatch.setattr(warmup, "OURS", (__name__.split(".")[0],))  # this file's kernels
    with warmup.FirstRun("verlet", None, said.append, True) as first:
        assert outer(1.0) == 3.0
    assert said == [warmup.FIRST_RUN.format("")]
    assert first.said and first.seconds > 0.0
    assert counted.done == 2  # outer, and inner compiled while typing it: not numba's max
    with warmup.FirstRun("verlet", None, said.append, True) as again:
        assert outer(2.0) == 5.0
    assert len(said) == 1 and not again.said and again.seconds == 0.0


def test_compiles_inside_start_are_not_watched_again(monkeypatch):
    """A kernel compiled by start counts on start's bar and in its time, not a second time
    as a compile outside it; start says the message with its estimate."""
    outer = _fresh_kernels()

    class Compiling(_Job):
        def compile(self):
            assert outer(1.0) == 3.0

    said, watched, bars = [], [], []
    monkeypatch.setattr(warmup, "counter", lambda *a: watched.append(1) or _Counted(None))
    monkeypatch.setattr(warmup, "bar", lambda *a: bars.append(_Counted(*a)) or bars[-1])
    monkeypatch.setattr(warmup, "OURS", (__name__.split(".")[0],))
    monkeypatch.setattr(warmup, "sim_jobs",
                        lambda system: [Compiling("pipeline.physics.system:energy_guard")])
    monkeypatch.setattr(warmup, "integrator_jobs",
                        lambda integrator, system: (_Job("s", True), []))
    monkeypatch.setattr(warmup, "split", lambda jobs, render, step: (jobs, [], False))
    with warmup.FirstRun("verlet", None, said.append, True) as first:
        first.start(None, None)
        first.finish(SimpleNamespace(integrator="verlet", system=None))
    assert said == [warmup.FIRST_RUN.format(", about 0 s")]  # energy_guard's 0.3 s
    assert watched == [] and bars[0].done == bars[0].total == 1 and first.seconds > 0.0


def test_a_mesh_scenes_early_jobs_are_its_projection_and_sweep():
    """early_jobs types the mesh's kernels from a stand-in table exactly as the scene's
    System does (else this process would compile them again, the helper's work wasted), and
    gives nothing for a scene without a mesh."""
    from pipeline.scene import load_scene
    from pipeline.simulation import cloth_model
    from pipeline.physics.system import build_system

    bowl = load_scene(SCENES / "bowl.json")
    early = warmup.early_jobs(bowl)
    assert [job.name for job in early] == ["pipeline.physics.colliders.mesh:project",
                                           "pipeline.physics.colliders:sweep_mesh"]
    jobs = warmup.sim_jobs(build_system(bowl, cloth_model(bowl)))
    assert all(job in jobs for job in early)
    assert warmup.early_jobs(load_scene(SCENES / "sphere.json")) == []


def test_a_mesh_cloth_on_a_mesh_collider_has_the_same_early_jobs_as_its_system(tmp_path):
    """early_jobs counts a mesh cloth's points from its file (the stand-in table's loop over
    the points is chosen by their number)."""
    from pipeline.scene import load_scene
    from pipeline.simulation import cloth_model
    from pipeline.physics.system import build_system

    path, overrides = _mesh_variants(tmp_path)[2]
    scene = load_scene(path, overrides)
    early = warmup.early_jobs(scene)
    assert [job.name for job in early] == ["pipeline.physics.colliders.mesh:project",
                                           "pipeline.physics.colliders:sweep_mesh"]
    jobs = warmup.sim_jobs(build_system(scene, cloth_model(scene)))
    assert all(job in jobs for job in early)


@pytest.mark.parametrize("model", ["classic", "fem"])
def test_start_shares_out_a_mesh_cloths_kernels(tmp_path, monkeypatch, model):
    """start on a mesh cloth's System hands its own kernels to the split (an unknown job
    there would make start give up and compile everything on first use)."""
    from pipeline.scene import load_scene
    from pipeline.simulation import cloth_model
    from pipeline.physics.system import build_system

    path, overrides = _mesh_variants(tmp_path)[0 if model == "classic" else 3]
    scene = load_scene(path, overrides + ['wind={"velocity": [3.0, 0.0, 1.0]}'])
    model_ = cloth_model(scene)
    system = build_system(scene, model_)
    shared = []
    monkeypatch.setattr(warmup.Job, "cached", lambda job: False)
    monkeypatch.setattr(warmup.Job, "compile", lambda job: None)
    monkeypatch.setattr(warmup, "split", lambda jobs, render, step: shared.append(jobs) or (
        jobs, [], False))
    with warmup.FirstRun("verlet") as first:
        first.start(model_, system)
        first.finish(SimpleNamespace(integrator="verlet", system=system))
    names = {job.name for job in shared[0]}
    mesh = {"pipeline.physics.mesh_wind:add_mesh_wind_force"} | set(
        MESH_MODELS[model == "fem"])
    assert mesh <= names and names <= set(warmup.COMPILE_SECONDS)
    assert not any(name.startswith(("pipeline.physics.forces:", "pipeline.physics.fem:",
                                    "pipeline.physics.wind:")) for name in names)


class _Stdin(io.BytesIO):
    """A helper's stdin that keeps what was written after it is closed."""

    def close(self):
        if not self.closed:
            self.kept = self.getvalue()
        super().close()


def test_a_mesh_scene_starts_the_helper_on_entering_on_the_mesh_kernels(monkeypatch):
    """With early jobs (a mesh collider), the helper starts as the run begins, on those;
    start then compiles the rest here and sends the helper no job twice (an empty share
    when one process is sooner), waits for it, and its reports made before start count on
    start's bar."""
    early = [_Job("pipeline.physics.colliders.mesh:project"), _Job("pipeline.physics.colliders:sweep_mesh")]
    reach = _Job("pipeline.physics.reach:reach_check")
    helpers, bars = [], []

    class Helper(_Helper):
        def __init__(self, *args, **kwargs):
            super().__init__(*args, **kwargs)
            self.stdin = _Stdin()
            self.stdout = io.BytesIO(b"project\nsweep_mesh\n" + warmup.SIMULATION_DONE + b"\n")
            helpers.append(self)

    monkeypatch.setattr(warmup, "early_jobs", lambda scene: early)
    monkeypatch.setattr(warmup.subprocess, "Popen", Helper)
    monkeypatch.setattr(warmup, "bar", lambda *a: bars.append(_Counted(*a)) or bars[-1])
    monkeypatch.setattr(warmup, "sim_jobs", lambda system: early + [reach])
    monkeypatch.setattr(warmup, "integrator_jobs",
                        lambda integrator, system: (_Job("s", cached=True), []))
    monkeypatch.setattr(warmup, "split", lambda jobs, render, step: (jobs, [], False))
    with warmup.FirstRun("verlet", scene=object()) as first:
        assert len(helpers) == 1  # on entering
        first.start(None, None)
        first.finish(SimpleNamespace(integrator="verlet", system=None))
    stream = io.BytesIO(helpers[0].stdin.kept)
    sent_early, (share, render) = pickle.load(stream), pickle.load(stream)
    assert [job.name for job in sent_early] == [job.name for job in early]
    assert share == [] and render is None
    assert reach.compiled == 1 and [job.compiled for job in early] == [0, 0]
    assert bars[0].total == bars[0].done == 3


_UNBLOCK = threading.Event()  # lets _Blocking's compile end (the helper unpickles a copy)


class _Blocking(_Job):
    def compile(self):
        assert _UNBLOCK.wait(120)


def test_the_helper_reads_its_second_payload_while_it_compiles_the_first(monkeypatch):
    """The helper takes all of stdin as it comes: the second payload (here 1.6 MB, more than
    a pipe holds) is written while the first jobs still compile, so this process, the
    writer, never waits on the helper; then it compiles both in order."""
    read_end, write_end = os.pipe()
    stdin = io.TextIOWrapper(os.fdopen(read_end, "rb"))
    stdout = io.TextIOWrapper(io.BytesIO())
    monkeypatch.setattr(sys, "stdin", stdin)
    monkeypatch.setattr(sys, "stdout", stdout)
    _UNBLOCK.clear()
    helper = threading.Thread(target=warmup._helper_main, daemon=True)
    helper.start()
    big = _Job("big")
    big.args = (np.zeros(200_000),)  # 1.6 MB pickled

    def write():
        with os.fdopen(write_end, "wb") as pipe:
            pickle.dump([_Blocking("early")], pipe)
            pickle.dump(([big], None), pipe)

    writer = threading.Thread(target=write, daemon=True)
    writer.start()
    writer.join(20)
    done_writing = not writer.is_alive()
    _UNBLOCK.set()
    helper.join(60)
    output = stdout.buffer.getvalue()
    stdin.close()
    assert done_writing and not helper.is_alive()
    assert output == b"early\nbig\n" + warmup.SIMULATION_DONE + b"\n"

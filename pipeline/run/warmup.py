"""The first run on a machine: compile a scene's numba kernels in two processes at once.

numba compiles a kernel on its first call and caches the machine code on disk; later runs
load it in milliseconds. On an empty cache compiling is nearly all of a short render (the
README's first command: 44 of its 46 s, 2026-11-24), and numba compiles in Python, under
the GIL, so threads cannot share the work. `FirstRun` finds which of a scene's kernels are
not cached yet, as soon as the Simulation has packed its System (before a FEM cloth's
stability limit runs the element kernels). When two processes would finish sooner
(`split`, by the kernels' measured compile times), a helper process (`python -m
pipeline.run.warmup`) compiles part of the simulator's and then the renderer's (if missing)
while this process compiles the rest and then the integrator's stepping kernel, from
its arguments' types (it calls most of the others through pointers, which need not be
compiled for that). The cache is safe for two writers (clothjit). Otherwise everything
missing is compiled here.

The helper is sent plain data (the packed System, the scene, the cloth model), never numba
objects. Its jobs are named `module:function`. Whatever it fails to do is compiled here
later: a failed helper costs time, never correctness. An interrupted run kills it.
"""
from __future__ import annotations

import contextlib
import importlib
import pickle
import queue
import subprocess
import sys
import threading
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Callable

import numpy as np

from pipeline.physics.fem import FemParams
from pipeline.physics.integrators import stepping_kernel

from .progress import bar, counter

# The simulation's kernels with their cold compile CPU times in seconds, one after the other
# in one process on an empty cache (2026-11-25 at night: the sphere, bowl and flag scenes'
# kernels, scaled so that the renderer's, measured beside them, is 11.2 s; that morning the
# FEM's elements and implicit Euler's solve and product, each alone, scaled by 0.88, the
# ratio of the FEM's old band estimate, 8.0 s, to its 9.1 s measured then; the FEM's
# internal forces from traced runs, 0.5-1.5 s; the classic internal forces 0.8 of their
# old 5.0 s since their two parallel loops are one kernel, five alternating runs). They
# split the kernels between this process and the helper (`split`) and give the estimate of
# the first-run message.
# The FEM's band loop since it is a pointer of its own, and the FEM's forces and filtered
# product without it: one traced first FEM run (2026-11-27 at 03:58, a slow moment: the
# elements 1.45x their earlier traced times; the loop 1.06 s, the forces 0.94 s, the
# product 0.65 s), scaled by 0.6.
# The colliders' range kernel and each kind's sweep since the sweeps are kernels of their own
# (colliders._sweep_of): one cold run per kind, traced (2026-11-27 at 02:50: the range
# 0.22-0.42 s, sphere 1.30 s, plane 1.34-1.57 s, box 2.06 s, mesh 2.24 s), scaled by 0.7;
# the keyframes' poses since they are a pointer of their own (0.97 s traced, scaled alike),
# and collide_all without them (its 2.8 s in a traced README run less update_poses' 1.2 s).
# The classic internal forces since their two passes are kernels of their own, called
# through pointers (forces.SpringKernels): 1.4-1.7 s and 0.7-0.8 s for each pass, against
# 5.4-5.7 s before, three rounds alternately in one process (2026-11-26), scaled by 0.73,
# the old estimate over the old time.
# Provot's limit since its pre-pass calls its two passes through pointers, and the passes:
# one traced cold README run (2026-11-27 at 01:12: 1.9 s, 0.52 s and 0.30 s against 3.3-3.9 s
# for the limit before), scaled by 0.75.
# Implicit Euler's Jacobian kernels (forces.JacobianKernels) and XPBD's sweeps since they are
# pointers chosen per model: one traced cold run each (2026-11-26 at 23:55), scaled by 0.85,
# collide_all's estimate over its time in that run.
# The springs' Jacobian product since its first pass is a pointer (forces._jacobian_pass) and
# it calls the forces' gather through a pointer, and implicit Euler's update since it is
# serial: two cold runs alternately with the tree before (2026-11-27 at 05:35: the product
# 1.9-2.0 s and its pass 0.7-0.9 s against 4.7-5.2 s, the update 0.15-0.22 s against
# 0.7-0.9 s), scaled by 0.6, the product's old estimate over its old time.
# Verlet's update since it is serial: 0.23-0.37 s of CPU against 1.14-1.39 s parallel, four
# rounds alternately (2026-11-27 at about 07:27), scaled alike; Euler's update since it is serial:
# 0.31-0.40 s against 0.86-0.98 s, two rounds alternately (07:30), scaled alike.
# collide_all since its loop over the points is a pointer chosen by the cloth's size: 0.53-0.59 s
# and the serial loop 0.21-0.25 s against 1.32-1.66 s with the parallel loop linked (three
# rounds each, 2026-11-27 at about 07:40 and 07:44), scaled by 0.95; Provot's limit since
# its pre-pass is a pointer chosen alike: 0.84-0.99 s and the serial pre-pass 0.18-0.23 s
# against 1.56-1.94 s with the parallel pre-pass linked (three rounds each, about 07:50), scaled
# by 0.79, its old estimate over its old time.
# A mesh cloth's kernels (pipeline.physics.mesh_forces, mesh_wind), each compiled with its
# linked callees (the forces' pointers with the forces the stability limit calls from
# Python, mesh_omega_max: the same types, so cached by that job): three cold processes
# each, alternately with the grid's internal forces, Provot, wind and FEM forces measured
# alike (2026-11-27 at about 17:00; CPU seconds: mesh internal forces 0.95-0.99, Provot
# 0.21, wind 2.25-2.37, FEM forces 1.71-1.82 after the rest angles' kernel the model builds
# first; the grid's nine kernels 5.50 s in all against their 8.65 s of estimates), scaled
# by 1.57, those estimates over those times.
# Two compiles at once each run about 1.25x slower (measured before collide_all's
# projections were inlined once: 15.2 s against 11.3 s alone, the renderer 13.4 s against
# 11.7 s): CONTENTION.
COMPILE_SECONDS = {
    "pipeline.physics.colliders:collide_all": 0.55,
    "pipeline.physics.colliders:_collide_serially": 0.2,
    "pipeline.physics.colliders:_collide_in_chunks": 0.85,
    "pipeline.physics.colliders:update_poses": 0.7,
    "pipeline.physics.colliders:_collide_range": 0.2,
    "pipeline.physics.colliders:sweep_sphere": 0.9,
    "pipeline.physics.colliders:sweep_plane": 1.0,
    "pipeline.physics.colliders:sweep_box": 1.4,
    "pipeline.physics.colliders:sweep_mesh": 1.6,
    "pipeline.physics.colliders.mesh:project": 3.2,
    "pipeline.physics.colliders:_unmoved": 0.05,
    "pipeline.physics.forces:internal_forces": 1.1,
    "pipeline.physics.forces:_direction_forces": 0.55,
    "pipeline.physics.forces:_gather": 0.55,
    "pipeline.physics.forces:fem_internal_forces": 0.6,
    "pipeline.physics.self_collision:self_collide": 2.1,
    "pipeline.physics.self_collision:self_collide_in_chunks": 3.4,
    "pipeline.physics.self_collision:_push_members": 0.8,
    "pipeline.physics.constraints:limit_stretch": 0.7,
    "pipeline.physics.constraints:_mark_serially": 0.15,
    "pipeline.physics.constraints:_mark_in_chunks": 0.7,
    "pipeline.physics.constraints:_flag_long": 0.4,
    "pipeline.physics.constraints:_pack_mask": 0.25,
    "pipeline.physics.reach:reach_check": 0.9,
    "pipeline.physics.system:motion_summary": 0.45,
    "pipeline.physics.system:energy_guard": 0.3,
    "pipeline.physics.wind:add_wind_force": 1.2,
    "pipeline.physics.wind:_band": 3.3,
    "pipeline.physics.fem:_triangles": 3.7,
    "pipeline.physics.fem:_hinges": 4.0,
    "pipeline.physics.fem:_bands_of_parity": 0.7,
    "pipeline.physics.fem:fem_filtered_jacobian_product": 0.4,
    "pipeline.physics.integrators.implicit_euler:solve_step": 3.6,
    "pipeline.physics.forces:spring_prepare": 1.9,
    "pipeline.physics.forces:spring_product": 1.2,
    "pipeline.physics.forces:_jacobian_pass": 0.45,
    "pipeline.physics.forces:spring_diagonal": 0.25,
    "pipeline.physics.forces:fem_prepare": 0.4,
    "pipeline.physics.forces:fem_product": 1.0,
    "pipeline.physics.forces:fem_diagonal": 0.5,
    "pipeline.physics.integrators.xpbd:solve_springs": 0.85,
    "pipeline.physics.integrators.xpbd:solve_fem": 2.7,
    "pipeline.physics.integrators.verlet:_update_all": 0.25,
    "pipeline.physics.integrators.implicit_euler:_update": 0.1,
    "pipeline.physics.integrators.euler:euler_update": 0.3,
    "pipeline.physics.integrators.rk4:_stage": 0.65,
    "pipeline.physics.integrators.rk4:_finish": 0.4,
    "pipeline.physics.mesh_forces:mesh_internal_forces": 1.55,
    "pipeline.physics.mesh_forces:mesh_fem_internal_forces": 3.5,
    "pipeline.physics.mesh_forces:mesh_limit_stretch": 0.35,
    "pipeline.physics.mesh_wind:add_mesh_wind_force": 3.6,
    # a mesh cloth's implicit Euler and XPBD kernels: set beside the grid's of the same
    # kind (the XPBD sweeps' cold compiles measured 0.33 and 0.85 s against the grid's
    # 0.49 and 1.37 s), not traced
    "pipeline.physics.mesh_forces:mesh_spring_prepare": 1.5,
    "pipeline.physics.mesh_forces:mesh_spring_apply": 1.5,
    "pipeline.physics.mesh_forces:mesh_spring_diagonal": 0.4,
    "pipeline.physics.mesh_forces:mesh_fem_prepare": 0.4,
    "pipeline.physics.mesh_forces:mesh_fem_apply": 3.0,
    "pipeline.physics.mesh_forces:mesh_fem_diagonal": 1.0,
    "pipeline.physics.mesh_xpbd:solve_mesh_springs": 0.6,
    "pipeline.physics.mesh_xpbd:solve_mesh_fem": 1.7,
    # robust contact's, one cold process (2026-11-28, selfCollision at 20x20, CPU seconds with
    # the linked callees: robust_contact 2.95, _visit 8.6, _tangles 2.25, where the course
    # kernels above took 0.45-0.75 of their estimates), scaled by 1.45
    "pipeline.physics.contact:robust_contact": 4.3,
    "pipeline.physics.contact:_visit": 12.5,
    "pipeline.physics.contact:_tangles": 3.3,
    # VBD's (issue 44), one of each for every model and cloth: one cold process, CPU seconds
    # with the contact terms in the descent (2026-11-28: sphere.json _predict 1.35 s, with
    # self-contact's pair search about 2.4; _sweep 5.2; descend_in_chunks 1.26), not scaled
    "pipeline.physics.integrators.vbd:_predict": 2.0,
    "pipeline.physics.integrators.vbd:_sweep": 5.3,
    "pipeline.physics.integrators.vbd:descend": 0.2,
    "pipeline.physics.integrators.vbd:descend_in_chunks": 1.2,
    "pipeline.physics.integrators.vbd:_velocities": 0.15,
    # robust contact's colliders: one cold process (2026-11-28, sphere.json with
    # self-collision, CPU seconds with the linked callees: robust_colliders 2.84, the
    # sphere's and box's stage 2 3.28), scaled by 1.45 as robust contact's above
    "pipeline.physics.collider_contact:robust_colliders": 4.1,
    "pipeline.physics.collider_contact:solid_faces": 4.8,
    # robust contact's mesh colliders (issue 43), one cold process each, CPU seconds
    # (2026-11-28, the robust bowl and open bowl of benchmarks/contact.py), not scaled
    "pipeline.physics.mesh_contact:mesh_colliders": 0.6,
    "pipeline.physics.mesh_contact:solid_stage": 7.0,
    "pipeline.physics.mesh_contact:sheet_stage": 5.9,
}
# every renderer kernel for one shader: 11.2 s alone, but beside the simulator's kernels
# they took 11.3-13.1 s in the helper where those took 1.24-1.33x their time alone
# (2026-11-25, four cold README runs traced), so 9.5 s before CONTENTION; 8.5 since the
# fragment stage's helpers have no Python entry and the setup's are not inlined (63aa934,
# 1198cfe): at 9.5, two traced cold README runs ended here 0.96 and 0.64 s after the helper;
# at 8.5, three runs 0.96 and 0.87 s after it and 1.05 s before it (2026-11-27, 10:12-10:14)
RENDER_SECONDS = 8.5
# Each integrator's stepping kernel (its passes called through pointers), 3.4 s before its
# update went through a pointer too (State.update, rk4's State.stage and .finish: jobs of
# their own); since, alternately with the tree before, Verlet's 2.45-3.20 s against
# 4.02-4.65 s, implicit Euler's 3.30-3.97 s against 4.73-5.19 s, rk4's 3.25-3.39 s against
# 5.91-6.27 s, Euler's 3.88-4.95 s against 4.79-5.42 s, each scaled by 3.4 / the old time;
# since reach_check is a pointer and the stepping kernels have no C wrapper, scaled by 0.87
# (Verlet's on the sphere scene, six rounds alternately with b40265a, 2026-11-27 at 06:05:
# 2.79-3.83 s of CPU against 3.24-4.12 s, every round lower, 3.31 against 3.81 s on average);
# Verlet's then 3.0: in four traced cold README runs (2026-11-27 at about 07:12) it took
# 2.90-3.76 s where the kernels compiled beside it took 1.03-1.35x their estimates (1.13x
# on average), and this process ended 0.5-1.7 s after the helper
# VBD's: 2.9 s of CPU, measured with its pointers' jobs (above), not scaled
STEP_SECONDS = {"verlet": 3.0, "euler": 2.5, "symplectic-euler": 2.5, "rk4": 1.65,
                "implicit-euler": 2.2, "xpbd": 3.0, "vbd": 2.9}
HELPER_START = 0.5  # the helper's start: a new interpreter importing the package
CONTENTION = 1.25


@dataclass
class Job:
    """One kernel to compile: `module:function` and arguments of the types it is called with;
    `linked`: the stepping kernel calls it directly, not through a pointer (compiled in this
    process before the stepping kernel, which reuses it)."""

    name: str
    args: tuple
    linked: bool = False

    @classmethod
    def of(cls, dispatcher, args: tuple, linked: bool = False) -> Job:
        """The job of compiling `dispatcher` for `args`."""
        return cls(f"{dispatcher.py_func.__module__}:{dispatcher.py_func.__name__}", args,
                   linked)

    def dispatcher(self):
        module, function = self.name.split(":")
        return getattr(importlib.import_module(module), function)

    def cached(self) -> bool:
        """Compiled in this process already, or in numba's disk cache for these types."""
        from clothjit import argument_types

        disp = self.dispatcher()
        sig = argument_types(disp, self.args)
        return sig in disp.overloads or any(key[0] == sig for key in _cache_index(disp))

    def compile(self) -> None:
        from clothjit import argument_types

        disp = self.dispatcher()
        disp.compile(argument_types(disp, self.args))


def _cache_index(disp) -> list[tuple]:
    """The keys of a dispatcher's fresh disk cache for this machine ([] if none)."""
    cache = getattr(disp, "_cache", None)
    if cache is None or not hasattr(cache, "_cache_file"):
        return []
    magic = disp.targetctx.codegen().magic_tuple()
    return [key for key in cache._cache_file._load_index() if key[1] == magic]


def kernel_pointers(system) -> list:
    """The System's KernelPointers that its kernels call: the stepping kernels' passes
    (System.kernels), Provot's pre-pass and its passes, the colliders' point range and loop
    over the points, mesh projection, sweeps and keyframe poses, the wind's band and the
    FEM's elements, robust contact's visits and colliders' passes (not the absent ones of
    passes the scene does not use)."""
    kernels = system.kernels
    mask = system.mask
    pointers = [*kernels._replace(springs=None), *kernels.springs, mask.flag, mask.pack,
                mask.mark, *_table_pointers(system.colliders)]
    if system.wind is not None and hasattr(system.wind, "band"):  # a mesh's wind has none
        pointers.append(system.wind.band)
    if isinstance(system.fem, FemParams):  # absent for the classic grid; a mesh's (MeshFem)
        # has no element pointers
        pointers += [system.fem.triangles, system.fem.hinges, system.fem.bands]
    if system.contact is not None:  # robust contact's pair visits, its colliders' passes
        c = system.contact
        pointers += [c.visit, c.mesh_pass, c.solid_stage, c.sheet_stage, c.solid_pass]
    return [p for p in pointers if p is not None and p.present]


def _table_pointers(table) -> list:
    """A collider table's KernelPointers (absent ones too)."""
    return [table.range, table.points, table.mesh, table.sphere, table.plane, table.box,
            table.mesh_sweep, table.poses]


def early_jobs(scene) -> list[Job]:
    """For a scene with a mesh collider, the mesh's projection and sweep, typed from a
    stand-in table (colliders.stand_in_table): the helper compiles them while this process
    builds the mesh's distance grid, whose own kernels compile first (4-5 s); the table's
    other kernels are shared out later, as usual. None for other scenes."""
    from pipeline.physics.colliders import mesh, stand_in_table

    colliders = scene.colliders
    if not any(type(c) is mesh.SCENE_TYPE for c in colliders):
        return []
    table = stand_in_table(colliders, cloth_points(scene))
    return [Job.of(p.dispatcher, p.argtypes) for p in (table.mesh, table.mesh_sweep)]


def cloth_points(scene) -> int:
    """The number of the cloth's points: the grid's, or the mesh file's once welded (read
    once: pipeline.physics.cloth_mesh keeps what it loaded)."""
    c = scene.cloth
    if c.mesh is None:
        return c.num_width_points * c.num_height_points
    from pipeline.physics.cloth_mesh import load_cloth_mesh

    return len(load_cloth_mesh(c.mesh).points)


def sim_jobs(system) -> list[Job]:
    """The kernels every integrator calls once per step (and a FEM cloth's stability limit),
    with arguments of the types the integrators pass (wind and self-collision only when the
    scene has them). Most are called through pointers (clothjit.KernelPointer): jobs of
    their own, not compiled with their callers."""
    s = system
    x = np.ascontiguousarray(s.x0, dtype=np.float64)
    last, f = x.copy(), np.zeros_like(x)
    linked = {"pipeline.physics.system:motion_summary": (x, last, s.x0, s.mass, s.gravity),
              "pipeline.physics.system:energy_guard": (0.0, 0.0, s.gravity, s.total_mass,
                                               s.slack_speed)}
    jobs = [Job(n, a, True) for n, a in linked.items()]
    # the stability limit's (system.stability_limit); a mesh cloth's (mesh_omega_max) calls
    # the forces its internal-forces pointer calls, with the same types: compiled (and
    # cached) with that pointer's job, so no job of its own
    if not s.classic and isinstance(s.fem, FemParams):
        jobs.append(Job("pipeline.physics.fem:fem_filtered_jacobian_product",
                        (s.fem.x_rest, s.fem, x, f)))
    if s.contact is not None and s.contact.self_on:  # the check for a start crossing itself
        from pipeline.physics.contact import tangles_call

        jobs.append(Job.of(*tangles_call(s.x0, s.contact, np.zeros((1, 2), np.int64))))
    return jobs + [Job.of(p.dispatcher, p.argtypes) for p in kernel_pointers(s)]


def integrator_jobs(integrator: str, system) -> tuple[Job, list[Job]]:
    """The stepping kernel of `integrator` for `system`, typed as its State calls it, and
    the kernels its State holds pointers to (implicit Euler's solve and Jacobian product),
    those of sim_jobs aside."""
    from pipeline.physics.integrators import integrator_module

    kernel = stepping_kernel(integrator)
    state = integrator_module(integrator).State(system)
    shared = {(p.dispatcher, p.argtypes) for p in kernel_pointers(system)}  # sim_jobs'
    jobs = {(p.dispatcher, p.argtypes): Job.of(p.dispatcher, p.argtypes)
            for p in _pointers_in(list(vars(state).values())) if p.present}
    return (Job.of(kernel, state.arguments(system, 0, 0)),
            [job for key, job in jobs.items() if key not in shared])


def _pointers_in(values: list) -> list:
    """The KernelPointers among `values` and in the (nested) NamedTuples among them."""
    from clothjit import KernelPointer

    found = []
    for value in values:
        if isinstance(value, KernelPointer):
            found.append(value)
        elif isinstance(value, tuple):
            found += _pointers_in(list(value))
    return found


def split(jobs: list[Job], render: bool, step: float) -> tuple[list[Job], list[Job], bool]:
    """(this process's jobs, the helper's, whether to start the helper): the stepping
    kernel's linked callees here, each other job, longest first, to the side where
    estimate_seconds ends sooner, this process ending with the stepping kernel (`step`
    seconds, 0 if cached) and the helper with the renderer's (`render`); the helper only
    when that beats compiling everything here, two compiles at once being slower."""
    alone = estimate_seconds(jobs, [], render, step, False)
    here = [job for job in jobs if job.linked]
    helper: list[Job] = []
    # each side's seconds kept as running sums (estimate_seconds' sums, in the same order)
    mine, theirs = sum(COMPILE_SECONDS[j.name] for j in here), 0
    for job in jobs:
        if job.linked:
            continue
        seconds = COMPILE_SECONDS[job.name]
        if (_in_two_processes(mine + seconds, theirs, render, step)
                <= _in_two_processes(mine, theirs + seconds, render, step)):
            here.append(job)
            mine += seconds
        else:
            helper.append(job)
            theirs += seconds
    if _in_two_processes(mine, theirs, render, step) < alone:
        return here, helper, True
    return list(jobs), [], False


@dataclass
class RenderJob:
    """A tiny frame of the scene with the shader and supersampling of the real ones."""

    scene: Any
    model: Any
    shader: str
    aa: int

    def run(self) -> None:
        from .frames import render_frame

        render_frame(self.scene, self.model.x0.T.copy(), self.model, self.shader, 16, 16,
                     self.aa)

    def cached(self) -> bool:
        import shading
        from shading.shade import fragment_stage

        key = shading.shaders.get_shader(self.shader).stage_key()
        # (key, extras): the stage this scene's frames run, the plain one without shadows,
        # occlusion or a collider's own shader (shade._fragment_stage)
        rs = self.scene.render
        extras = int(rs.shadows or rs.ambient_occlusion
                     or any(c.shader not in (None, self.shader) for c in self.scene.colliders))
        return any(len(sig) > 1 and getattr(sig[-2], "literal_value", None) == key
                   and getattr(sig[-1], "literal_value", None) == extras
                   for sig, *_ in _cache_index(fragment_stage))


def estimate_seconds(here: list[Job], helper: list[Job], render: bool, step: float,
                     two_processes: bool) -> float:
    """The first-run message's estimate (on this 2-core machine, idle): in two processes,
    this process's share then the stepping kernel (`step` seconds), while the helper (from
    HELPER_START) compiles its share then the renderer's (`render`); else all of it in this
    process."""
    mine = sum(COMPILE_SECONDS[j.name] for j in here)
    theirs = sum(COMPILE_SECONDS[j.name] for j in helper)
    if two_processes:
        return _in_two_processes(mine, theirs, render, step)
    return mine + theirs + step + (RENDER_SECONDS if render else 0.0)


def _in_two_processes(mine: float, theirs: float, render: bool, step: float) -> float:
    """estimate_seconds in two processes from each one's compile seconds."""
    rendering = RENDER_SECONDS if render else 0.0
    return CONTENTION * max(mine + step, HELPER_START + theirs + rendering)


FIRST_RUN = "compiling kernels for this machine (first run only{})"
OURS = ("pipeline", "shading")  # the packages whose kernels the watch counts


class FirstRun:
    """A first run's compiling, around building the Simulation (the CLI's render):

        with FirstRun(integrator, render, say, progress) as first:
            sim = Simulation(scene, prepare=first.start)
            first.finish(sim)
        first.seconds  # all the compiling, for the summary

    `start` (called by the Simulation once its model and System are built, before its
    stability limit: a FEM cloth's calls the element kernels) compiles the kernels numba
    has not cached, the scene's `integrator`'s stepping kernel among them, in two processes
    when that is sooner, the helper going on with the renderer's (`render`: a callable
    making the RenderJob from the cloth model, or None). `finish` waits for the helper;
    leaving the `with` early kills it.
    A compile outside them (a mesh collider's distance grid while the System is built) is
    watched: the first says the first-run message (`say`), `progress` counts our kernels on
    stderr, and its time counts in `seconds`. Given the `scene`, a scene with a mesh
    collider starts the helper on entering, on the mesh's projection and sweep
    (early_jobs), while this process compiles the distance grid's kernels."""

    def __init__(self, integrator: str, render: Callable[[Any], RenderJob] | None = None,
                 say: Callable[[str], None] | None = None, progress: bool = False,
                 scene: Any = None):
        self.integrator, self.render, self.say, self.progress = integrator, render, say, progress
        self.scene = scene
        self.seconds = 0.0
        self.said = False
        self._inside = False  # in start or finish, which time their own compiling
        self._depth = 0
        self._since = 0.0
        self._watched = None  # the count of kernels compiled outside start and finish
        self._bar = None
        self._helper: subprocess.Popen | None = None
        self._reader: threading.Thread | None = None
        self._ready: threading.Event | None = None  # set once the helper's simulation
        # kernels are compiled (or it died)
        self._early: list[Job] = []  # the helper's first jobs (early_jobs)
        self._reported = 0  # kernels the helper reported before the bar was made
        self._reports = threading.Lock()

    def __enter__(self) -> FirstRun:
        from numba.core import event

        first = self

        class Listener(event.Listener):  # numba calls it in the compiling thread
            def on_start(self, ev) -> None:
                first._begin()

            def on_end(self, ev) -> None:
                first._end(ev.data["dispatcher"].py_func.__module__.split(".")[0] in OURS)

        self._listener = Listener()
        event.register("numba:compile", self._listener)
        if self.scene is not None:
            try:
                self._early = [job for job in early_jobs(self.scene) if not job.cached()]
            except Exception:  # numba's cache layout changed: compile on first use
                self._early = []
            if self._early:
                self._start_helper(self._early)
        return self

    def __exit__(self, *exc) -> None:
        from numba.core import event

        event.unregister("numba:compile", self._listener)
        self._close_watched()
        self._end_helper(kill=True)  # left early (an error, a signal): the helper goes too
        if self._bar is not None:
            self._bar.close()

    # --- compiles outside start and finish ---------------------------------------------
    def _begin(self) -> None:
        if self._inside:
            return
        if self._depth == 0:
            if not self.said:
                self.said = True
                if self.say is not None:
                    self.say(FIRST_RUN.format(""))
            if self._watched is None and self._bar is None:
                self._watched = counter("compile", "kernel", self.progress)
            self._since = time.perf_counter()
        self._depth += 1

    def _end(self, ours: bool) -> None:
        if self._inside:
            return
        self._depth -= 1
        if ours and self._watched is not None:  # not numba's own library functions
            self._watched.update(1)
        if self._depth == 0:
            self.seconds += time.perf_counter() - self._since

    def _close_watched(self) -> None:
        if self._watched is not None:
            self._watched.close()
            self._watched = None

    @contextlib.contextmanager
    def _own(self):
        """A phase of start or finish: its wall time is compiling time."""
        self._close_watched()
        self._inside = True
        since = time.perf_counter()
        try:
            yield
        finally:
            self._inside = False
            self.seconds += time.perf_counter() - since

    # --- the two phases ---------------------------------------------------------------
    def start(self, model, system) -> None:
        """Compile the missing simulation kernels of `system` and the stepping kernel (this
        process's share and the helper's, which then goes on with the renderer's); return
        once the simulation's are all compiled."""
        try:
            stepping, pointed = integrator_jobs(self.integrator, system)
            jobs = sorted((j for j in sim_jobs(system) + pointed
                           if j not in self._early and not j.cached()),
                          key=lambda job: COMPILE_SECONDS[job.name], reverse=True)  # longest first
            step = 0.0 if stepping.cached() else STEP_SECONDS[self.integrator]
            render = self.render(model) if self.render is not None else None
            if render is not None and render.cached():
                render = None
        except Exception:  # numba's cache layout changed: compile on first use, as before
            return
        if not (jobs or step or render or self._early):
            return
        with self._own():
            here, helper, two_processes = split(jobs, render is not None, step)
            if self.say is not None:
                seconds = estimate_seconds(here, helper, render is not None, step,
                                           two_processes)
                self.say(f"compiling the other kernels (about {seconds:.0f} s)" if self.said
                         else FIRST_RUN.format(f", about {seconds:.0f} s"))
                self.said = True
            with self._reports:
                self._bar = bar(len(self._early) + len(jobs) + int(step > 0)
                                + int(render is not None), "compile", "kernel", self.progress,
                                0)
                self._bar.update(self._reported)
            there = render if two_processes else None  # the renderer's, in the helper
            if two_processes and self._helper is None:
                self._start_helper([])
            if self._helper is not None:  # (started on entering, for a mesh's kernels)
                self._send_rest(helper, there)
            # the stepping kernel from its arguments' types: the kernels it calls through
            # pointers need not be compiled yet (the helper's may not be)
            for job in here + ([stepping] if step else []):
                job.compile()
                self._bar.update(1)
            if self._ready is not None:
                self._ready.wait()
            if render is not None and there is None:
                render.run()
                self._bar.update(1)

    def finish(self, sim) -> None:
        """Compile the kernels of the integrator the Simulation chose, if fidelity auto chose
        another than the scene's; wait for the helper's renderer."""
        missing = []
        if sim.integrator != self.integrator:
            stepping, pointed = integrator_jobs(sim.integrator, sim.system)
            missing = [job for job in pointed + [stepping] if not job.cached()]
        if self._bar is None and not missing:  # nothing was missing, or start failed
            return
        with self._own():
            for job in missing:
                job.compile()
            self._end_helper(kill=False)
            if self._bar is not None:
                self._bar.close()
                self._bar = None

    def _end_helper(self, kill: bool) -> None:
        """Wait for the helper (`kill`: kill it first) and close its pipe."""
        if self._helper is None:
            return
        if kill:
            self._helper.kill()
        self._helper.wait()
        if not kill:
            self._reader.join()  # its last reports are on the bar
        for pipe in (self._helper.stdin, self._helper.stdout):
            with contextlib.suppress(OSError):
                pipe.close()
        self._helper = None

    def _start_helper(self, early: list[Job]) -> None:
        """Start the helper on its first jobs, `early`; the rest follow (_send_rest). It
        reports each kernel it finishes on its stdout; self._ready is set once its
        simulation kernels are compiled (or it died)."""
        # Run from the folder holding this package: `-m` puts the working folder first on
        # the path, and a checkout there (a user's clone beside the installed package) would
        # be imported instead, its kernels cached apart from ours (numba keys the cache on
        # the source file's path).
        root = Path(__file__).resolve().parents[2]
        proc = subprocess.Popen([sys.executable, "-m", "pipeline.run.warmup"], cwd=root,
                                stdin=subprocess.PIPE, stdout=subprocess.PIPE,
                                stderr=subprocess.DEVNULL)
        self._helper = proc
        ready = self._ready = threading.Event()

        def follow() -> None:  # the helper's reports, until it ends (or dies)
            for line in proc.stdout:
                if line.strip() == SIMULATION_DONE:
                    ready.set()
                    continue
                with self._reports:
                    if self._bar is None:
                        self._reported += 1
                    else:
                        self._bar.update(1)
            ready.set()

        self._reader = threading.Thread(target=follow, name="warmup-helper", daemon=True)
        self._reader.start()
        self._send(early)

    def _send_rest(self, helper: list[Job], render: RenderJob | None) -> None:
        """The helper's other jobs, and the renderer's (None: not there)."""
        self._send((helper, render))
        try:
            self._helper.stdin.close()
        except OSError:
            pass

    def _send(self, payload) -> None:
        try:
            pickle.dump(payload, self._helper.stdin, protocol=pickle.HIGHEST_PROTOCOL)
            self._helper.stdin.flush()
        except OSError:  # the helper died: its share is compiled on use
            pass


SIMULATION_DONE = b"simulation"


def _helper_main() -> None:
    """The helper process: compile the jobs read from stdin (a list, then a list and the
    RenderJob or None), one line per kernel, then the renderer's (if sent). stdin is read
    in a thread as it comes: the second payload (a RenderJob carries the cloth model, 0.1-1
    MB) is written while the first jobs compile, and the pipe would otherwise keep the
    writer, the compiling process, waiting."""
    payloads: queue.Queue = queue.Queue()
    source = sys.stdin.buffer

    def read() -> None:
        # the other process ended (EOF, a broken pipe), or stdin was closed here
        with contextlib.suppress(EOFError, OSError, ValueError):
            while True:
                payloads.put(pickle.load(source))
        payloads.put(None)

    threading.Thread(target=read, name="warmup-stdin", daemon=True).start()
    out = sys.stdout.buffer

    def report(line: bytes) -> None:
        out.write(line + b"\n")
        out.flush()

    def compile_all(jobs: list[Job]) -> None:
        for job in jobs:
            job.compile()
            report(job.name.encode())

    early = payloads.get()
    if early is None:
        return
    compile_all(early)
    rest = payloads.get()
    if rest is None:
        return
    helper, render = rest
    compile_all(helper)
    report(SIMULATION_DONE)
    if render is not None:
        render.run()
        report(b"render")


if __name__ == "__main__":
    _helper_main()

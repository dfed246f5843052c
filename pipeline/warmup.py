"""The first run on a machine: compile a scene's numba kernels in two processes at once.

numba compiles a kernel on its first call and caches the machine code on disk; later runs
load it in milliseconds. On an empty cache compiling is nearly all of a short render (the
README's first command: 44 of its 46 s, 2026-11-24), and numba compiles in Python, under
the GIL, so threads cannot share the work. `warm_up` finds which of a scene's kernels are
not cached yet. When two processes would finish sooner (`split`, by the kernels' measured
compile times), a helper process (`python -m pipeline.warmup`) compiles part of the
simulator's and then the renderer's (if missing) while this process compiles the rest,
then this process compiles the integrator's stepping kernel on top of both (loading the
helper's work from the cache). The cache is safe for two writers (shading.jit). Otherwise
everything missing is compiled here, as before.

The helper is sent plain data (the packed System, the scene, the cloth model), never numba
objects. Its jobs are named `module:function`. Whatever it fails to do is compiled here
later: a failed helper costs time, never correctness. An interrupted run kills it.
"""
from __future__ import annotations

import importlib
import pickle
import subprocess
import sys
import threading
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Callable

import numpy as np

from .progress import bar, counter

# The simulation's kernels with their cold compile CPU times in seconds, one after the other
# in one process on an empty cache (2026-11-25: the sphere, bowl and flag scenes' kernels,
# scaled so that the renderer's, measured beside them, is 11.2 s; the FEM's band
# alone the same day). They split the kernels between this process and the helper
# (`split`) and give the estimate of the first-run message.
# Two compiles at once each run about 1.25x slower (measured before collide_all's
# projections were inlined once: 15.2 s against 11.3 s alone, the renderer 13.4 s against
# 11.7 s): CONTENTION.
COMPILE_SECONDS = {"pipeline.colliders:collide_all": 2.3,
                   "pipeline.colliders:_collide_range": 2.7,
                   "pipeline.colliders.mesh:project": 3.2, "pipeline.colliders:_unmoved": 0.05,
                   "pipeline.forces:internal_forces": 5.0,
                   "pipeline.self_collision:self_collide": 3.1,
                   "pipeline.constraints:limit_stretch": 2.5,
                   "pipeline.reach:reach_check": 0.9, "pipeline.system:motion_summary": 0.45,
                   "pipeline.system:energy_guard": 0.3, "pipeline.wind:add_wind_force": 1.2,
                   "pipeline.wind:_band": 3.3, "pipeline.fem:_band": 8.0}
# every renderer kernel for one shader: 11.2 s alone, but beside the simulator's kernels
# they took 11.3-13.1 s in the helper where those took 1.24-1.33x their time alone
# (2026-11-25, four cold README runs traced), so 9.5 s before CONTENTION
RENDER_SECONDS = 9.5
STEP_SECONDS = 3.4  # the integrator's stepping kernel (its passes called through pointers)
HELPER_START = 0.5  # the helper's start: a new interpreter importing the package
CONTENTION = 1.25


@dataclass
class Job:
    """One kernel to compile: `module:function` and arguments of the types it is called with."""

    name: str
    args: tuple

    def dispatcher(self):
        module, function = self.name.split(":")
        return getattr(importlib.import_module(module), function)

    def cached(self) -> bool:
        """Compiled in this process already, or in numba's disk cache for these types."""
        from shading.jit import argument_types

        disp = self.dispatcher()
        sig = argument_types(disp, self.args)
        return sig in disp.overloads or any(key[0] == sig for key in _cache_index(disp))

    def compile(self) -> None:
        from shading.jit import argument_types

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
    """The System's KernelPointers: the stepping kernels' passes (System.kernels), the
    colliders' point range and mesh projection, the wind's band and the FEM's elements."""
    table = system.colliders
    pointers = [p for p in system.kernels if p is not None] + [table.range, table.mesh]
    if system.wind is not None:
        pointers.append(system.wind.band)
    if system.fem is not None:
        pointers += [system.fem.triangles, system.fem.hinges]
    return pointers


def sim_jobs(system) -> list[Job]:
    """The kernels every integrator calls once per step, with arguments of the types the
    integrators pass (self-collision only when the scene turns it on: otherwise numba
    prunes it from the stepping kernel), longest to compile first. Most are called through
    pointers (shading.jit.KernelPointer): jobs of their own, not compiled with their
    callers."""
    s = system
    x = np.ascontiguousarray(s.x0, dtype=np.float64)
    last, v, f = x.copy(), np.zeros_like(x), np.zeros_like(x)
    args = {"pipeline.wind:add_wind_force": (x, v, 0.0, s.wind, f),
            "pipeline.system:motion_summary": (x, last, s.x0, s.mass, s.gravity),
            "pipeline.system:energy_guard": (0.0, 0.0, s.gravity, s.total_mass, s.slack_speed),
            "pipeline.reach:reach_check": (x, s.reach, s.colliders.active, s.thickness)}
    if s.wind is None:  # pruned from the stepping kernel
        del args["pipeline.wind:add_wind_force"]
    for pointer in kernel_pointers(s):
        disp = pointer.dispatcher
        args[f"{disp.py_func.__module__}:{disp.py_func.__name__}"] = pointer.argtypes
    return [Job(n, args[n]) for n in sorted(args, key=COMPILE_SECONDS.get, reverse=True)]


def split(jobs: list[Job], render: bool, step: bool) -> tuple[list[Job], list[Job], bool]:
    """(this process's jobs, the helper's, whether to start the helper): each job, longest
    first, to the side where estimate_seconds ends sooner, this process ending with the
    stepping kernel and the helper with the renderer's (when `render`); the helper only
    when that beats compiling everything here, two compiles at once being slower."""
    alone = estimate_seconds(jobs, [], render, step, False)
    here: list[Job] = []
    helper: list[Job] = []
    for job in jobs:
        if (estimate_seconds(here + [job], helper, render, step, True)
                <= estimate_seconds(here, helper + [job], render, step, True)):
            here.append(job)
        else:
            helper.append(job)
    if estimate_seconds(here, helper, render, step, True) < alone:
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
        return any(sig and getattr(sig[-1], "literal_value", None) == key
                   for sig, *_ in _cache_index(fragment_stage))


def _stepping_cached(sim) -> bool:
    """Whether the integrator's stepping kernel is cached for this scene's System type."""
    disp = sim.stepping_kernel
    system_type = disp.typeof_pyval(sim.system)
    return (any(sig and sig[0] == system_type for sig in disp.overloads)
            or any(sig and sig[0] == system_type for sig, *_ in _cache_index(disp)))


def estimate_seconds(here: list[Job], helper: list[Job], render: bool, step: bool,
                     two_processes: bool) -> float:
    """The first-run message's estimate (on this 2-core machine, idle): in two processes,
    both simulation shares (the helper's from HELPER_START), then the stepping kernel here
    while the helper compiles the renderer's (`render`); else all of it in this process."""
    mine = sum(COMPILE_SECONDS[j.name] for j in here)
    theirs = sum(COMPILE_SECONDS[j.name] for j in helper)
    stepping = STEP_SECONDS if step else 0.0
    rendering = RENDER_SECONDS if render else 0.0
    if two_processes:
        helper_done = HELPER_START + theirs
        return CONTENTION * max(max(mine, helper_done) + stepping, helper_done + rendering)
    return mine + theirs + stepping + rendering


FIRST_RUN = "compiling kernels for this machine (first run only{})"
OURS = ("pipeline", "shading")  # the packages whose kernels CompileWatch counts


class CompileWatch:
    """Numba compiling in this process before the warm-up can start: a FEM cloth's
    stability limit and a mesh collider's distance grid are computed while the Simulation
    is built, and a first run compiles their kernels there (about 16 s for the FEM's
    element passes, 2026-11-24). Inside `with`, the first compile says the first-run
    message (`say`), `progress` counts our kernels compiled on stderr, and `seconds` sums
    the time spent compiling (numba's library functions included), for the summary."""

    def __init__(self, say: Callable[[str], None] | None = None, progress: bool = False):
        self.say, self.progress = say, progress
        self.seconds = 0.0
        self.said = False
        self._kernels = None
        self._depth = 0
        self._start = 0.0

    def __enter__(self) -> CompileWatch:
        from numba.core import event

        watch = self

        class Listener(event.Listener):  # numba calls it in the compiling thread
            def on_start(self, ev) -> None:
                watch._begin()

            def on_end(self, ev) -> None:
                watch._end(ev.data["dispatcher"].py_func.__module__.split(".")[0] in OURS)

        self._listener = Listener()
        event.register("numba:compile", self._listener)
        return self

    def __exit__(self, *exc) -> None:
        from numba.core import event

        event.unregister("numba:compile", self._listener)
        if self._kernels is not None:
            self._kernels.close()

    def _begin(self) -> None:
        if self._depth == 0:
            if not self.said:
                self.said = True
                if self.say is not None:
                    self.say(FIRST_RUN.format(""))
                self._kernels = counter("compile", "kernel", self.progress)
            self._start = time.perf_counter()
        self._depth += 1

    def _end(self, ours: bool) -> None:
        self._depth -= 1
        if ours:  # not numba's own library functions compiled along with them
            self._kernels.update(1)
        if self._depth == 0:
            self.seconds += time.perf_counter() - self._start


def warm_up(sim, render: RenderJob | None, say: Callable[[str], None] | None = None,
            progress: bool = False, announced: bool = False) -> float:
    """Compile what the scene's simulation (and `render`, if given) need and numba has not
    cached, in two processes when both sides need it. `say` gets the first-run message
    (`announced`: a CompileWatch said it already); `progress` shows a bar of the kernels
    compiled on stderr. Returns the seconds spent compiling (0.0 when everything was
    cached)."""
    start = time.perf_counter()
    try:
        jobs = [j for j in sim_jobs(sim.system) if not j.cached()]
        step = not _stepping_cached(sim)
        render_cold = render is not None and not render.cached()
    except Exception:  # numba's cache layout changed: compile on first use, as before
        return 0.0
    if not (jobs or step or render_cold):
        return 0.0
    here, helper, two_processes = split(jobs, render_cold, step)
    if say is not None:
        seconds = estimate_seconds(here, helper, render_cold, step, two_processes)
        say(f"compiling the other kernels (about {seconds:.0f} s)" if announced
            else FIRST_RUN.format(f", about {seconds:.0f} s"))
    kernels = bar(len(jobs) + int(step) + int(render_cold), "compile", "kernel", progress, 0)
    try:
        if two_processes:
            _in_two_processes(sim, here, helper, step, render if render_cold else None,
                              kernels)
        else:
            for job in jobs:
                job.compile()
                kernels.update(1)
            if step:
                sim.compile_kernels()
                kernels.update(1)
            if render_cold:
                render.run()
                kernels.update(1)
    finally:
        kernels.close()
    return time.perf_counter() - start


def _in_two_processes(sim, here: list[Job], helper: list[Job], step: bool,
                      render: RenderJob | None, kernels) -> None:
    """Both shares at once; the helper reports each kernel it finishes on its stdout. This
    process compiles the stepping kernel last (if `step`: not cached), once the helper's
    simulation kernels it calls are cached."""
    payload = pickle.dumps((helper, render), protocol=pickle.HIGHEST_PROTOCOL)
    # Run from the folder holding this package: `-m` puts the working folder first on the
    # path, and a checkout there (a user's clone beside the installed package) would be
    # imported instead, its kernels cached apart from ours (numba keys the cache on the
    # source file's path).
    root = Path(__file__).resolve().parent.parent
    proc = subprocess.Popen([sys.executable, "-m", "pipeline.warmup"], cwd=root,
                            stdin=subprocess.PIPE, stdout=subprocess.PIPE,
                            stderr=subprocess.DEVNULL)
    simulation_ready = threading.Event()

    def follow() -> None:  # the helper's reports, until it ends (or dies)
        for line in proc.stdout:
            if line.strip() == SIMULATION_DONE:
                simulation_ready.set()
            else:
                kernels.update(1)
        simulation_ready.set()

    reader = threading.Thread(target=follow, name="warmup-helper", daemon=True)
    reader.start()
    try:
        try:
            proc.stdin.write(payload)
            proc.stdin.close()
        except OSError:  # the helper died at once: its share is compiled below, on use
            pass
        for job in here:
            job.compile()
            kernels.update(1)
        simulation_ready.wait()
        if step:
            sim.compile_kernels()
            kernels.update(1)
        proc.wait()
        reader.join()
    except BaseException:
        proc.kill()
        proc.wait()
        raise
    finally:
        proc.stdout.close()


SIMULATION_DONE = b"simulation"


def _helper_main() -> None:
    """The helper process: compile the jobs read from stdin, one line per kernel, then the
    renderer's (if sent)."""
    helper, render = pickle.loads(sys.stdin.buffer.read())
    out = sys.stdout.buffer
    for job in helper:
        job.compile()
        out.write(job.name.encode() + b"\n")
        out.flush()
    out.write(SIMULATION_DONE + b"\n")
    out.flush()
    if render is not None:
        render.run()
        out.write(b"render\n")
        out.flush()


if __name__ == "__main__":
    _helper_main()

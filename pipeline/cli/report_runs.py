"""`render report`'s simulations: one per variant, in a process pool (--jobs) or on Dask,
each keeping only the frames the report shows."""
from __future__ import annotations

import dataclasses
import multiprocessing
import os
import time
import warnings
from dataclasses import dataclass, field
from typing import Callable, Sequence

import numpy as np

from pipeline.run import signals

from .options import cluster_requested
from .report_plan import ReportPlan


@dataclass
class VariantRun:
    """What a simulation produced: positions (N, 3) at each wanted frame it reached."""

    positions: dict[int, np.ndarray]
    error: str | None  # divergence message; frames after it are missing
    warnings: list[str]
    seconds: float  # wall time of the simulation
    #: {(width, height): pipeline.view.framing.Framing} of the shot's frames it reached (a scene
    #: with no camera; empty otherwise)
    framings: dict = field(default_factory=dict)


def simulate_variant(scene_path: str, overrides: Sequence[str], frames: Sequence[int],
                     threads: int | None = None,
                     on_frame: Callable[[], None] | None = None,
                     shot: Sequence[int] = (), sizes: Sequence[tuple[int, int]] = ()
                     ) -> VariantRun:
    """Simulate one variant frame by frame (as `render` does) up to max(frames), keeping a
    copy of the positions at each frame in `frames`, and, for a scene with no camera, the
    framing (pipeline.view.framing) of the frames in `shot` for each image size in `sizes`.
    Runs in a worker process for sweeps: every argument and the result are picklable (on
    Dask `scene_path` is the file's bytes, a SceneFile). `threads`: numba threads to use
    here (restored afterwards); the results do not depend on it."""
    if threads is None:
        return _simulate(scene_path, overrides, frames, on_frame, shot, sizes)
    from clothjit import numba_threads

    with numba_threads(threads):
        return _simulate(scene_path, overrides, frames, on_frame, shot, sizes)


def _simulate(scene_path, overrides, frames, on_frame, shot, sizes) -> VariantRun:
    from pipeline.physics.errors import DivergenceError
    from pipeline.scene import load_scene
    from pipeline.simulation import Simulation
    from pipeline.view.framing import Framing, framed_points

    t0 = time.perf_counter()
    wanted = sorted(set(int(f) for f in frames))
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        scene = load_scene(scene_path, list(overrides))
        sim = Simulation(scene, shot_seconds=wanted[-1] / scene.simulation.frames_per_sec
                         if wanted else None)
    msgs = [str(w.message).splitlines()[0] for w in caught if str(w.message)]
    framed = set(shot) if scene.camera is None else set()
    framings = {tuple(size): Framing(*size) for size in sizes} if framed else {}

    def reached(j: int) -> None:
        if j in framed:
            points = framed_points(scene, sim.positions, j / scene.simulation.frames_per_sec)
            for framing in framings.values():
                framing.add(points)

    positions: dict[int, np.ndarray] = {}
    error = None
    current = 0
    reached(0)
    try:
        for j in wanted:
            while current < j:
                sim.advance(1)
                current += 1
                reached(current)
                if on_frame is not None:
                    on_frame()
            positions[j] = sim.positions.copy()
    except DivergenceError as exc:
        error = str(exc).strip().splitlines()[0]
    return VariantRun(positions, error, msgs, time.perf_counter() - t0, framings)


def _simulate_indexed(task: tuple) -> tuple[int, VariantRun]:
    """simulate_variant in a pool worker, keeping the variant's index with the result."""
    index, *args = task
    return index, simulate_variant(*args)


#: scene blocks that change only how frames are drawn: variants differing only in these
#: share one simulation
DRAWING_BLOCKS = ("render", "light")


def shared_simulations(variants) -> tuple[list, list[int]]:
    """(the variants to simulate, re-indexed 0, 1, ...; for each variant, the index of the
    one whose simulation it shows): variants whose sweep overrides differ only in
    DRAWING_BLOCKS keys (a render.shadows or light.radius sweep) share one."""
    first: dict[tuple, int] = {}
    chosen, of = [], []
    for v in variants:
        key = tuple(o for o in v.overrides if o.split("=", 1)[0].split(".")[0].strip()
                    not in DRAWING_BLOCKS)
        if key not in first:
            first[key] = len(chosen)
            chosen.append(dataclasses.replace(v, index=len(chosen)))
        of.append(first[key])
    return chosen, of


def run_simulations(plan: ReportPlan, jobs: int | None = None, progress=None
                    ) -> list[VariantRun]:
    """Every variant's simulation (shared between variants that differ only in how they
    are drawn: shared_simulations): one Dask task each with --workers / --scheduler, else
    in this process when there is one simulation or one job, else in a pool of `jobs`
    spawned processes. Results do not depend on where they ran."""
    chosen, of = shared_simulations(plan.variants)
    if len(chosen) < len(plan.variants):
        runs = run_simulations(dataclasses.replace(plan, variants=chosen), jobs, progress)
        return [runs[k] for k in of]
    jobs = plan.jobs if jobs is None else jobs
    frames = plan.needed_frames
    n = len(plan.variants)
    if cluster_requested(plan):
        return _simulate_on_dask(plan, frames, progress)
    workers = max(1, min(jobs, n))
    if workers == 1:
        runs = []
        for v in plan.variants:
            tick = progress.update if (progress is not None and n == 1) else None
            # one numba thread, as `render` simulates (its "split" pipeline): on a small
            # cloth the kernels' thread barriers cost more than they save
            runs.append(simulate_variant(plan.scene_path, plan.overrides + list(v.overrides),
                                         frames, threads=1, on_frame=tick,
                                         shot=plan.shot_frames, sizes=plan.image_sizes))
            if progress is not None and n > 1:
                progress.update(1)
        return runs
    threads = max(1, (os.cpu_count() or 1) // workers)
    ctx = multiprocessing.get_context("spawn")  # fork after numba threads started is unsafe
    runs: list[VariantRun | None] = [None] * n
    tasks = [(v.index, plan.scene_path, plan.overrides + list(v.overrides), frames, threads,
              None, plan.shot_frames, plan.image_sizes) for v in plan.variants]
    with signals.deferred():  # every worker started and sent its set-up, or none
        pool = ctx.Pool(workers)
    try:
        for index, result in pool.imap_unordered(_simulate_indexed, tasks):
            runs[index] = result
            if progress is not None:
                progress.update(1)
        pool.close()
    finally:
        pool.terminate()  # on an error or a signal: no worker is left running
        pool.join()
    return runs  # type: ignore[return-value]


def _simulate_on_dask(plan: ReportPlan, frames: list[int], progress) -> list[VariantRun]:
    """One task per variant; each ships the scene file's bytes and the overrides."""
    import uuid

    import distributed

    from pipeline.cluster import client as cluster
    from pipeline.scene import SceneFile

    scene = SceneFile.read(plan.scene_path)
    runs: list[VariantRun | None] = [None] * len(plan.variants)
    with cluster.connect(plan) as client:
        run = f"clothpipe-report-{uuid.uuid4().hex}"
        futures = {client.submit(simulate_variant, scene, plan.overrides + list(v.overrides),
                                 frames, 1, None, plan.shot_frames, plan.image_sizes,
                                 key=f"{run}-{v.index}"): v.index
                   for v in plan.variants}
        for future in distributed.as_completed(futures, loop=client.loop):
            runs[futures[future]] = future.result()
            if progress is not None:
                progress.update(1)
        plan.cluster = cluster.where(client, plan)
    return runs  # type: ignore[return-value]


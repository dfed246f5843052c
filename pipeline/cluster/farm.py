"""One long render on Dask: `render SCENE --out shot.mp4 --workers N | --scheduler ADDR`.

The simulation stays sequential: it is one task (`simulate_shot`), on one worker. Every
few frames it submits a task that rasterises those frames (`render_chunk`, the positions
inside the task: any worker can run it again if the one holding it dies) and puts that
task's future on a Dask queue. The client takes the futures off the queue in order and
writes the images as they arrive, through the same atomic writers as `render`; frames
are bit for bit those of the one-process run (same kernels, same inputs).

Faults: a killed worker's tasks run again elsewhere (Dask reschedules them). If it held the
simulation, the simulation starts again from frame 0 and submits the same chunk keys: the
scheduler keeps the chunks it already has, and the client skips chunks it has written.
Stopping the client (a signal) sets a Dask event the simulation checks between chunks,
and releases every future (Dask cancels what has not run).
"""
from __future__ import annotations

import math
import time
from dataclasses import dataclass, field
from functools import lru_cache

import numpy as np

#: Chunks in flight at most per worker thread (queued and rendering): bounds memory.
DEPTH_PER_THREAD = 2
#: Frames per chunk at most, and the chunks per worker thread aimed at (load balance).
CHUNK_MAX = 8
CHUNKS_PER_THREAD = 4
POLL = 0.05  # seconds between looks at the queue while it is empty (client) or full
# (simulation); a queue's own timeouts would log an error on the scheduler each time


@dataclass
class Shot:
    """What the simulation task needs: all plain data."""

    scene: object  # pipeline.scene.SceneFile
    overrides: tuple[str, ...]
    sim_frames: list[int]  # simulator frame of each output frame
    sim_fps: float
    view: dict  # render_frame keywords: shader, width, height, aa (+ shot: a framed camera)
    chunk: int  # output frames per render task
    depth: int  # chunks on the queue at most
    run: str  # names of this run's keys, queue and event

    def chunks(self) -> list[range]:
        n = len(self.sim_frames)
        return [range(a, min(n, a + self.chunk)) for a in range(0, n, self.chunk)]

    def key(self, k: int) -> str:
        return f"{self.run}-frames-{k:06d}"

    @property
    def seconds(self) -> float:
        """How long the shot is simulated (its last output frame's simulator time)."""
        return self.sim_frames[-1] / self.sim_fps


@dataclass
class SimResult:
    seconds: float
    warnings: list[str] = field(default_factory=list)
    notes: list[str] = field(default_factory=list)  # fidelity auto's summary


def chunk_size(frames: int, threads: int) -> int:
    """Output frames per render task: about CHUNKS_PER_THREAD tasks per worker thread,
    at most CHUNK_MAX frames each."""
    return max(1, min(CHUNK_MAX, math.ceil(frames / (CHUNKS_PER_THREAD * threads))))


@lru_cache(maxsize=4)
def _scene_and_model(scene, overrides: tuple[str, ...]):
    """The scene and its cloth model as the simulation builds them, once per worker."""
    from pipeline.scene import load_scene
    from pipeline.simulation import cloth_model

    loaded = load_scene(scene, list(overrides))
    return loaded, cloth_model(loaded)


def render_chunk(scene, overrides: tuple[str, ...], view: dict, times: list[float],
                 positions: np.ndarray) -> tuple[np.ndarray, float]:
    """Rasterise frames (positions (K, N, 3) at simulated times `times`) on one numba
    thread; returns the images (K, H, W, 3) uint8 and the seconds it took."""
    from clothjit import numba_threads
    from pipeline.run.frames import render_frame

    t0 = time.perf_counter()
    loaded, model = _scene_and_model(scene, overrides)
    with numba_threads(1):
        images = [render_frame(loaded, p, model, time=t, **view)
                  for p, t in zip(positions, times)]
    return np.stack(images), time.perf_counter() - t0


def simulate_shot(shot: Shot) -> SimResult:
    """The simulation task: advance through the planned frames; per chunk, submit its
    render task and put the future on the run's queue (waits while the client is
    DEPTH_PER_THREAD chunks per thread behind). Stops early if the run's event is set.
    It secedes from the worker's thread pool at once, so that render tasks can run on its
    worker too (else a chunk queued behind it there would wait for the whole shot)."""
    import warnings

    import distributed

    from clothjit import numba_threads
    from pipeline.scene import load_scene
    from pipeline.simulation import Simulation

    distributed.secede()
    client = distributed.get_client()
    queue = distributed.Queue(f"{shot.run}-chunks", client=client)
    stop = distributed.Event(f"{shot.run}-stop", client=client)
    t0 = time.perf_counter()
    with warnings.catch_warnings(record=True) as caught, numba_threads(1):
        warnings.simplefilter("always")
        sim = Simulation(load_scene(shot.scene, list(shot.overrides)),
                         shot_seconds=shot.seconds)
        seconds = time.perf_counter() - t0  # simulating only, not waiting for the client
        current = 0
        for k, frames in enumerate(shot.chunks()):
            t0 = time.perf_counter()
            positions = []
            for i in frames:
                if current < shot.sim_frames[i]:
                    sim.advance(shot.sim_frames[i] - current)
                    current = shot.sim_frames[i]
                positions.append(sim.positions.copy())
            seconds += time.perf_counter() - t0
            times = [shot.sim_frames[i] / shot.sim_fps for i in frames]
            future = client.submit(render_chunk, shot.scene, shot.overrides, shot.view, times,
                                   np.stack(positions), key=shot.key(k))
            if not _wait_for_room(queue, shot.depth, stop):
                break
            queue.put(future)
    notes = [sim.stepper.summary_text()] if sim.stepper is not None else []
    return SimResult(seconds, [str(w.message).splitlines()[0] for w in caught if str(w.message)],
                     notes)


def _wait_for_room(queue, depth: int, stop) -> bool:
    """Wait while `queue` holds `depth` items; False once the run is stopped."""
    while not stop.is_set():
        if queue.qsize() < depth:
            return True
        time.sleep(POLL)
    return False


def frame_shot_here(scene_file, overrides, plan):
    """The framing (pipeline.view.framing) of a scene with no camera over the whole shot,
    simulated in this process first: the simulation is a small share of a long render, and
    every render task then draws with the same camera as a one-process run."""
    from pipeline.scene import load_scene
    from pipeline.simulation import Simulation
    from pipeline.view.framing import frame_shot

    scene = load_scene(scene_file, list(overrides))
    sim = Simulation(scene, shot_seconds=plan.shot_seconds)

    def shot():
        current = 0
        for j in plan.shot_frames:
            sim.advance(j - current)
            current = j
            yield sim.positions, j / plan.sim_fps

    return frame_shot(scene, shot(), plan.width, plan.height)


def next_chunk(queue, sim, shot: Shot, k: int):
    """The future of chunk k: the next one on the queue that is not a chunk already
    written (a simulation run again after its worker died submits them again). Raises
    what the simulation raised if it fails first."""
    while True:
        if not queue.qsize():
            if sim.status in ("error", "cancelled"):
                sim.result()  # raises the simulation's error (a DivergenceError...)
            if sim.status == "finished" and not queue.qsize():
                raise RuntimeError(f"the simulation ended before render task {k}")
            time.sleep(POLL)
            continue
        future = queue.get()
        if future.key == shot.key(k):
            return future

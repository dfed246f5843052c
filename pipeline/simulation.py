"""Running a scene: the `Simulation` object and `simulate()`."""
from __future__ import annotations

import math
import os
import time
import warnings
from collections.abc import Callable
from pathlib import Path

import numpy as np

from clothjit import LOOK_EVERY, adjust_threads
from pipeline.physics.errors import (DivergenceError, SelfCollisionWarning, StabilityWarning,
                                     StartTangledWarning)
from pipeline.physics.contact import with_room
from pipeline.physics.integrators import integrator_module
from pipeline.physics.limit_reach import LimitStop, beyond_reach, limit_watch
from pipeline.physics.model import ClothModel, build_model
from pipeline.physics.overlap import resolve_start_inside
from pipeline.physics.system import System, build_system, stability_limit
from pipeline.scene import Scene, load_scene


def cloth_model(scene: Scene, initial_positions: np.ndarray | None = None) -> ClothModel:
    """The cloth model a simulation of `scene` starts from (points that start inside a
    collider moved out), also what frames are drawn with (the default camera looks at
    its initial positions)."""
    model = build_model(scene, initial_positions)
    resolve_start_inside(scene, model)
    return model


def _warn_short_edges(scene: Scene, model: ClothModel) -> None:
    """A mesh cloth with self-collision whose shortest edge is under 2 x thickness: the
    course's repulsion pushes those neighbours apart, fighting the springs."""
    s = model.mesh.springs
    shortest = float(s.rest[:s.structural].min())
    if shortest < 2.0 * scene.cloth.thickness:
        count = int(np.count_nonzero(s.rest[:s.structural] < 2.0 * scene.cloth.thickness))
        warnings.warn(
            f"{model.mesh.source.name}: {count} edge{'s' * (count != 1)} shorter than "
            f"2 x cloth.thickness ({2.0 * scene.cloth.thickness:g} m; the shortest "
            f"{shortest:.3g} m): self-collision pushes their ends apart; use a smaller "
            "cloth.thickness or a coarser mesh", SelfCollisionWarning, stacklevel=3)


def _warn_start_tangled(model: ClothModel, contact) -> None:
    """Under robust contact, a cloth that starts crossing itself: say how much and where
    (robust contact keeps new crossings from forming; it does not undo these)."""
    from pipeline.physics.contact import tangles

    found = np.zeros((3, 2), np.int64)
    count = tangles(model.x0, contact, found)
    if count == 0:
        return

    def name(p: int) -> str:
        return str(p) if model.mesh is not None else f"[{p % model.nw}, {p // model.nw}]"

    e, t = found[0]
    edge = " and ".join(name(p) for p in contact.edges[e])
    tri = ", ".join(name(p) for p in contact.triangles[t])
    warnings.warn(
        f"the cloth starts crossing itself: {count} edge-triangle crossing"
        f"{'s' * (count != 1)} at t = 0 (e.g. the edge between points {edge} through the "
        f"triangle of points {tri}); robust contact keeps new crossings from forming but "
        "does not untangle these", StartTangledWarning, stacklevel=3)


class Simulation:
    """A scene being simulated, stepped by hand or frame by frame.

    Attributes: `scene`, `model` (the cloth model: springs, pins, masses), `system` (the same
    packed for the kernels), `positions` (N, 3) and `last_positions` (N, 3) views of the current
    state, `pinned` (N,) bool, `springs` (a, b, rest, type arrays in SPEC order), `step_count`,
    `time` (seconds simulated).

    Under fidelity auto an FEM cloth may run on a coarser grid (pipeline.fidelity.fem_grid): `coarse`
    is then that grid's Simulation, whose `system`, state and `stepper` these are, and
    `positions` are its positions carried to the file's grid (`model`): computed, not views.
    """

    def __init__(
        self,
        scene: Scene | dict | str | os.PathLike,
        *,
        initial_positions: np.ndarray | None = None,
        shot_seconds: float | None = None,
        prepare: Callable[[ClothModel, System], None] | None = None,
        grid: bool = True,
    ) -> None:
        """`shot_seconds`: how long the caller will simulate, if known (fidelity auto's pilots
        cover no more than that). `prepare`: called with the cloth model and its System once
        they are built, before the stability limit and the integrator use any kernel (a
        first run compiles them there: pipeline.run.warmup). `grid`: False keeps the file's FEM
        grid under fidelity auto (no grid pilot)."""
        self.scene = scene if isinstance(scene, Scene) else load_scene(scene)
        #: fidelity auto, FEM: the coarse grid's Simulation where the shot runs on one
        self.coarse: Simulation | None = None
        self._on_file_grid = None
        self.model: ClothModel = cloth_model(self.scene, initial_positions)
        self.system: System = build_system(self.scene, self.model)
        if self.model.mesh is not None and self.system.self_collision:
            _warn_short_edges(self.scene, self.model)
        if prepare is not None:
            prepare(self.model, self.system)
        if self.system.contact is not None and self.system.contact.self_on:
            # after `prepare`: a first run compiles its kernel beside the others
            _warn_start_tangled(self.model, self.system.contact)
        self.omega_max, self.dt_max = stability_limit(self.model)
        self.integrator = self.scene.simulation.integrator
        auto = self.scene.simulation.fidelity == "auto"
        self.integrator_reasons: list[str] = []
        if auto:
            from pipeline.fidelity.plan import choose_integrator

            self.integrator, self.integrator_reasons = choose_integrator(self.scene, self.dt_max)
            self.system = self.system._replace(colliders_last=True)
        module = integrator_module(self.integrator)
        self._state = module.State(self.system)
        self.step_count = 0
        #: the keyframed pins Provot's limit is watched against (limit_reach) until it
        #: stops, where they leave it no state; None when not watched
        self.limit_watch = limit_watch(self.system)
        #: where it stopped (LimitStop), None while it runs
        self.limit_stop: LimitStop | None = None
        self.step_limited = module.CONDITIONALLY_STABLE
        #: the frame-by-frame controller of fidelity "auto" (pipeline.fidelity.controller), else None
        self.stepper = None
        if auto:
            from pipeline.fidelity.controller import AutoStepper

            self.stepper = AutoStepper(self, shot_seconds)
        elif self.step_limited and self.system.dt > self.dt_max:
            warnings.warn(self.stability_message(), StabilityWarning, stacklevel=2)
        #: fidelity auto, FEM: the grid pilot's figures (pipeline.fidelity.fem_grid.GridChoice), why
        #: there was none, and the wall seconds it took here (simulating, for `render`)
        self.grid_choice = None
        self.grid_reason = ""
        self.grid_seconds = 0.0
        if (auto and grid and self.model.fem is not None and self.model.mesh is None
                and initial_positions is None):
            start = time.perf_counter()
            self._choose_grid(shot_seconds)
            self.grid_seconds = time.perf_counter() - start

    def _choose_grid(self, shot_seconds: float | None) -> None:
        from pipeline.fidelity.fem_grid import OnFileGrid, choose_grid

        choice, coarse, self.grid_reason = choose_grid(self, shot_seconds,
                                                       self.stepper.pilot_seconds)
        if coarse is not None:
            self.coarse = coarse
            self._on_file_grid = OnFileGrid(coarse.model, self.model, self.scene)
            self._state, self.stepper = coarse._state, coarse.stepper
            self.omega_max, self.dt_max = coarse.omega_max, coarse.dt_max
            self.integrator, self.integrator_reasons = (coarse.integrator,
                                                        coarse.integrator_reasons)
        self.grid_choice = self.stepper.grid = choice

    @property
    def system(self) -> System:
        return self._system if self.coarse is None else self.coarse.system

    @system.setter
    def system(self, system: System) -> None:
        self._system = system

    # --- state -------------------------------------------------------------------------
    @property
    def positions(self) -> np.ndarray:
        """Current positions, (N, 3) view (row-major points)."""
        if self._on_file_grid is not None:
            return self._on_file_grid.positions(self._state.x.T, self.time)
        return self._state.x.T

    @property
    def last_positions(self) -> np.ndarray:
        """Positions one step ago, (N, 3) (Verlet state)."""
        if self._on_file_grid is not None:
            return self._on_file_grid.positions(self._state.last.T, self.time - self.dt)
        return self._state.last.T

    @property
    def velocities(self) -> np.ndarray:
        v = self._state.velocity(self.system).T
        return v if self._on_file_grid is None else self._on_file_grid.velocities(v)

    @property
    def pinned(self) -> np.ndarray:
        return self.model.pinned.astype(bool)

    @property
    def springs(self) -> dict[str, np.ndarray]:
        """The spring list in SPEC order: endpoints a, b, rest length, type (0/1/2), enabled."""
        m = self.model
        return {"a": m.spring_a, "b": m.spring_b, "rest": m.spring_rest,
                "type": m.spring_type, "enabled": m.spring_enabled}

    @property
    def dt(self) -> float:
        return self.system.dt

    @property
    def time(self) -> float:
        if self.stepper is not None:
            return self.stepper.frame * self.stepper.frame_dt
        return self.step_count * self.system.dt

    @property
    def plan(self):
        """What will be modelled and why (pipeline.fidelity.plan.Plan)."""
        from pipeline.fidelity.plan import make_plan

        return make_plan(self)

    # --- stepping ----------------------------------------------------------------------
    def step(self, steps: int = 1) -> None:
        """Advance by `steps` time steps; raises DivergenceError if the run blows up. Under
        fidelity auto the steps are chosen per frame: use advance()."""
        if self.stepper is not None:
            raise ValueError("under fidelity auto the steps are chosen per frame: use advance()")
        adjust_threads()
        spf = self.system.steps_per_frame
        while self.limit_watch is not None and steps > 0:  # frame by frame until it stops
            run = min(steps, spf - self.step_count % spf)
            self._check_limit((self.step_count + run + spf - 1) // spf)
            self._steps(run)
            steps -= run
        if steps > 0:
            self._steps(steps)

    def _check_limit(self, frame: int) -> None:
        """Stop Provot's limit if the pins end frame `frame` beyond its reach."""
        t = frame / self.scene.simulation.frames_per_sec
        beyond = beyond_reach(self.limit_watch, self.system.x0, t)
        if beyond is not None:
            p, q, distance, reach = beyond
            self.limit_stop = LimitStop(frame, t, (p, q), distance, reach)
            self.system = self.system._replace(stretch_limit=False)
            self.limit_watch = None

    def _steps(self, steps: int) -> None:
        done, kinetic, bound = self._state.advance(self.system, steps, self.step_count)
        self.step_count += done
        self.make_contact_room()
        if done < steps or not kinetic <= bound:  # also catches a trip on the last step, NaN
            raise DivergenceError(self._divergence_message(kinetic, bound))

    def make_contact_room(self) -> None:
        """After steps: robust contact's candidate list gets room if it overflowed
        (contact.with_room; until then its steps visit the spatial hash)."""
        c = self.system.contact
        if c is not None and c.self_on:
            roomy = with_room(c)
            if roomy is not c:
                self.system = self.system._replace(contact=roomy)

    def advance(self, frames: int = 1) -> None:
        """Advance by whole frames (steps_per_frame steps each; fidelity auto: as chosen)."""
        if self.stepper is not None:
            for _ in range(frames):
                adjust_threads()
                if self.limit_watch is not None:
                    self._check_limit(self.stepper.frame + 1)
                self.stepper.advance_frame()
            return
        # in runs of about LOOK_EVERY seconds, so that the threads may follow the load between
        # them (step) without paying a kernel call per frame
        spf = self.system.steps_per_frame
        run = 1
        while frames > 0:
            run = min(run, frames)
            start = time.perf_counter()
            self.step(run * spf)
            seconds = time.perf_counter() - start
            frames -= run
            run = max(1, int(run * LOOK_EVERY / seconds)) if seconds > 0 else frames

    def frames(self, count: int):
        """Yield the positions (N, 3) after each of the next `count` frames (views: copy to keep)."""
        for _ in range(count):
            self.advance(1)
            yield self.positions

    # --- messages ----------------------------------------------------------------------
    def stability_message(self) -> str:
        spf = self.system.steps_per_frame
        needed = math.ceil(spf * self.system.dt / self.dt_max)
        c = self.scene.cloth
        stiff, key = ((f"cloth.fem.stretch = {c.fem.stretch:g} N/m", "cloth.fem.stretch")
                      if self.model.fem is not None else (f"ks = {c.ks:g}", "cloth.ks"))
        return (
            f"time step {self.system.dt:.3g} s exceeds the explicit stability limit "
            f"{self.dt_max:.3g} s of this cloth (omega_max = {self.omega_max:.4g} rad/s from "
            f"{stiff} and point mass {self.model.point_mass.min():.3g} kg): expect a "
            f"blow-up; use simulation.steps_per_frame >= {needed}, a smaller {key} or "
            f'simulation.integrator "implicit-euler"'
        )

    def _divergence_message(self, kinetic: float, bound: float) -> str:
        spf = self.system.steps_per_frame
        frame, step_in_frame = divmod(self.step_count - 1, spf)
        speed = float(np.sqrt(np.nanmax(np.sum(self.velocities**2, axis=1))))
        if not math.isfinite(kinetic) or not np.all(np.isfinite(self._state.x)):
            what = "positions became non-finite (NaN or infinity)"
        else:
            what = (f"kinetic energy {kinetic:.4g} J exceeds {bound:.4g} J, more than gravity "
                    f"can have supplied (max point speed {speed:.3g} m/s)")
        advice = (self.stability_message() if self.step_limited and self.system.dt > self.dt_max else
                  "use a larger simulation.steps_per_frame or a smaller "
                  + ("cloth.fem.stretch" if self.model.fem is not None else "cloth.ks"))
        if self.limit_stop is not None:  # the limit had kept the springs' explicit steps in check
            advice = (f"Provot's stretch limit stopped at frame {self.limit_stop.frame} (the "
                      "pins pull beyond its reach) and the springs alone hold the cloth; "
                      f'{advice}, or simulation.integrator "implicit-euler" or "vbd"')
        return (f"simulation diverged at frame {frame + 1}, step {step_in_frame + 1} of "
                f"{spf} (t = {self.time:.4f} s): {what}; {advice}")


def simulate(
    scene: Scene | dict | str | os.PathLike | Path,
    frames: int,
    *,
    initial_positions: np.ndarray | None = None,
) -> np.ndarray:
    """Positions after each of `frames` frames: float64 array (frames, N, 3)."""
    sim = Simulation(scene, initial_positions=initial_positions)
    out = np.empty((frames, sim.model.n, 3), dtype=np.float64)
    for f, positions in enumerate(sim.frames(frames)):
        out[f] = positions
    return out

"""`fidelity: auto`: model no more than a scene needs, within a tolerance in pixels.

The scene's physics is what it means at a converged step: the damping is a drag rate fixed
at the step the file gives (gamma = -ln(1 - c) / dt0; a step dt gets 1 - (1 - c)^(dt/dt0)),
Verlet integrates that drag exactly for a constant force (verlet.py, `force_dt2`) and starts
from rest with the matching start, and the colliders act after Provot's stretch limit so
that no point ends a step inside one. Then:

1. The step. The FEM's, by error control (step doubling over a frame): a frame is advanced
   twice from the same state, with m = n // 2 steps (B) and with n steps (A, kept). The
   local error of A is estimated as |A - B| / ((n/m)^p - 1) (p the integrator's order),
   measured on screen: the largest distance between a point's two projections through the
   scene's camera, in pixels of the rendered image. A frame is accepted when that is at
   most SAFETY times `tolerance_px`, else redone with more steps; the next frame's n follows
   the usual controller n' = n (err / target)^(1/p) (by at most GROWTH; lowered only below
   half the target). Estimates thin out while the error stays well below the target (at the
   fewest steps: while its trend stays below the target). n never
   goes below the stability floor (so that B is stable too), and a step the divergence
   guard rejects is redone with twice the steps.
   The classic model's, once for the shot, by a pilot: its stretch limit acts once per step,
   so the step count is part of the model and changing it mid-run starts a transient that
   per-frame doubling reads as error. The pilot runs the first PILOT_SECONDS (or the whole
   shot, if the caller says it is shorter: Simulation's `shot_seconds`) at n1 and 2 n1
   steps per frame side by side; the error of n steps is first order in the step (measured:
   docs/fidelity.md), C / n, and C = 2 n1 d from the two runs' screen distance d, taken at
   its largest over the pilot's second half (the swing after the release; the release's
   first snap is left out, docs/fidelity.md); n is the fewest steps that bring C / n to
   PILOT_TARGET tolerances (a third run at that n, at least 3 n1, checks the first order).
   The shot goes on from the pilot run with the fewest steps >= n where that costs no more
   than starting again at n (the run's frames are replayed: the same frames bit for bit),
   else starts again at n. Under contact, self-collision or gusty wind the classic model's
   motion depends on the step chaotically, and the file's steps stay (no pilot).
2. The integrator: Verlet, unless its stability floor makes implicit Euler cheaper per frame
   at the measured cost ratio of one implicit step to one Verlet step (IMPLICIT_COST).
3. Passes: pipeline.physics.reach skips self-collision and colliders where nothing can touch
   (bit-identical to running them).
4. Sleep: with nothing in the scene varying in time (no gusts, no keyframe still to come)
   and every point moving less than SLEEP_FRACTION of the tolerance per frame for
   SLEEP_TIME seconds, the cloth sleeps: later frames repeat it at no cost, until a
   keyframe starts.
5. The FEM grid: the coarsest grid whose error on screen a pilot on coarser grids bounds
   within the tolerance, drawn on the file's grid (pipeline.fidelity.fem_grid; Simulation runs it).
docs/fidelity.md has the calibration and the measured costs and errors.
"""
from __future__ import annotations

import math

import numpy as np

from pipeline.physics.forces import total_force_now
from pipeline.physics.reach import arm, budget_for
from pipeline.physics.system import System, damping_at, drag_gamma
from pipeline.scene import Scene

SAFETY = 0.5  # accepted estimate per frame: SAFETY * tolerance (calibrated: docs/fidelity.md)


SLEEP_FRACTION = 0.5  # quiet frame: no point moves this share of the tolerance ...


SLEEP_TIME = 0.5  # ... for this long, and the motion decays so that what is left ...


SLEEP_DRIFT = 0.25  # ... adds up to less than this share of the tolerance


SLEEP_HORIZON = 10.0  # seconds of motion counted when it does not decay


STABILITY_MARGIN = 0.9  # steps stay below this share of the explicit stability limit


#: order of the error in the step, for the step-doubling estimate (FEM model: the classic
#: model keeps the file's steps); Verlet's drag term is first order, which the estimate
#: sees through the velocity it compares (AutoStepper._ahead)
ORDER = {"verlet": 2, "implicit-euler": 1}


GROWTH = 1.5  # the steps per frame change by at most this factor from frame to frame


MAX_REDOS = 2  # a frame over the tolerance is redone at most this often, then kept


COARSE_RATIO = 1.25  # the coarse run has at most 1/this of the steps (>= the floor)


REARM_EVERY = 8  # frames between looks for passes that cannot act (pipeline.physics.reach) ...


MAX_REARM_EVERY = 64  # ... backing off to this while nothing can be skipped


PERSIST_FRAMES = 4  # a velocity error is weighed over at most this many frames


MAX_CHECK_EVERY = 16  # error estimates every frame, thinned out to this while far below


CHECK_COST = 1.5  # steps per kept step on a frame with an error estimate


PILOT_SECONDS = 1.0  # the classic model's pilot covers the shot's first second ...


PILOT_STEPS = 8  # ... at n1 >= this many steps per frame (and the stability floor) and 2 n1


#: the pilot's estimate of the largest error over its second half may reach this many
#: tolerances (calibrated on pinned2 and pinned4: the error at 1 s and 3 s is then about
#: one tolerance or less; docs/fidelity.md)
PILOT_TARGET = 2.0


#: the third run's distance from the 2 n1 run may exceed first order's prediction from
#: (n1, 2 n1) by at most this factor for more steps to count as more accuracy (at n3 = 4 n1
#: chaotic motion comes out near 2, first order near 1)
PILOT_CONVERGENCE = 4.0 / 3.0


#: the shot keeps the third run's steps n3 when the finer pair's estimate asks for at most
#: this many times n3 (the estimate's own spread: C from (n1, 2 n1) and from (2 n1, n3)
#: differ by 6-8 % on pinned2 and pinned4)
PILOT_SLACK = 1.15


REPLAYED = ("x", "last", "v")  # a pilot run's state kept per frame, to replay in the shot


REPLAY_BYTES = 256 << 20  # at most this much kept per pilot pass; a larger cloth starts again


#: cost of one implicit-Euler step in Verlet steps (benchmarks/sim.py --features, 2026-11-23)
IMPLICIT_COST = {"classic": 20.0, "fem": 41.9}


def metres_per_pixel(camera, points: np.ndarray) -> float:
    """The world length that projects to one pixel at the point of `points` (N, 3) nearest
    to the camera (perspective: 2 z tan(vfov / 2) / image height)."""
    eye = np.asarray(camera.eye)
    forward = np.asarray(camera.target) - eye
    forward /= np.linalg.norm(forward)
    depth = max(float(np.min((points - eye) @ forward)), camera.near)
    return 2.0 * depth * math.tan(math.radians(camera.vfov) / 2.0) / camera.height


def screen_distance(camera, a: np.ndarray, b: np.ndarray) -> float:
    """Largest distance in pixels between the projections of a[i] and b[i], (N, 3) each."""
    p = camera.project(np.concatenate((a, b)))[:, :2]  # one projection for both
    d = np.sqrt(np.sum((p[:len(a)] - p[len(a):]) ** 2, axis=1))
    return float(np.max(d)) if len(d) else 0.0


def gusty(scene: Scene) -> bool:
    """The scene's air varies in time (a steady wind does not)."""
    return scene.wind is not None and scene.wind.gust > 0


def wake_time(scene: Scene, t: float) -> float | None:
    """The earliest time >= t at which something in the scene varies in time (now, if it
    does now; None if never): gusts always vary, a keyframed collider while before its
    last key."""
    if gusty(scene):
        return t
    firsts = [c.keyframes[0].time for c in scene.colliders if c.keyframes]
    lasts = [c.keyframes[-1].time for c in scene.colliders if c.keyframes]
    if not lasts or t >= max(lasts):
        return None
    if any(f <= t < last for f, last in zip(firsts, lasts)):
        return t
    return min(f for f in firsts if f > t)


class AutoStepper:
    """Advances a Simulation's state frame by frame under `fidelity: auto`."""

    def __init__(self, sim, shot_seconds: float | None = None) -> None:
        from pipeline.view.framing import default_camera

        self.sim = sim
        scene: Scene = sim.scene
        s = scene.simulation
        self.scene = scene
        self.frame_dt = 1.0 / s.frames_per_sec
        self.base = sim.system  # the scene's own step: the damping rate is fixed there
        self.order = ORDER[sim.integrator]
        self.since_check = 0
        self.skip_passes = True  # False: every pass on every step (pipeline.physics.reach)
        self.watched = np.zeros(2, dtype=np.uint8)  # the premises armed (pipeline.physics.reach)
        self.armed_at = -REARM_EVERY
        #: frames between armings: REARM_EVERY while their premises hold, doubling up to
        #: MAX_REARM_EVERY while they break or nothing can be skipped
        self.rearm_every = REARM_EVERY
        self.tolerance = float(s.tolerance_px)
        self.camera = default_camera(scene, sim.model.x0.T, scene.render.width,
                                     scene.render.height)
        #: the fewest stable steps per frame; the error estimate's coarse run takes no fewer
        self.floor = (math.ceil(self.frame_dt / (STABILITY_MARGIN * sim.dt_max))
                      if sim.step_limited and math.isfinite(sim.dt_max) else 1)
        coarse = max(2, math.ceil(COARSE_RATIO * self.floor))  # an estimate's coarse run
        self.n_max = max(64 * coarse, 16 * s.steps_per_frame)
        #: the classic model's step count is part of the model (its stretch limit acts once
        #: per step): chosen once for the shot by a pilot; the FEM's per frame by doubling
        self.adaptive = s.model != "classic"
        self.n_min = coarse if self.adaptive else max(2, self.floor)
        self.pilot: dict | None = None  # the classic pilot's figures, once it has run
        self.grid = None  # the FEM grid pilot's figures (pipeline.fidelity.fem_grid.GridChoice)
        #: the classic model's motion under contact or gusts depends on the step
        #: chaotically (docs/fidelity.md): no pilot there, the file's steps; a steady wind
        #: gets the pilot (whose third run, where it asks for more steps, checks that they
        #: bring accuracy)
        self.chaotic = bool(scene.colliders or sim.system.self_collision or gusty(scene))
        self.shot_seconds = shot_seconds
        self.pilot_seconds = min(PILOT_SECONDS, shot_seconds or PILOT_SECONDS)
        #: (steps per frame (or a list per frame), per-frame states, end state) of the pilot
        #: run the shot goes on from, while its frames are replayed
        self.replay: tuple | None = None
        self.replay_first = 0  # the frame the replayed run starts at
        self.n = max(self.n_min, s.steps_per_frame)
        self.check_every = 1  # frames between error estimates: 1 .. MAX_CHECK_EVERY
        self.safety = SAFETY
        self.gamma = gamma = drag_gamma(self.base.damping, self.base.dt)
        #: how long a velocity error is weighed: the drag's time constant, within one and
        #: PERSIST_FRAMES frames (an oscillation bounds what a velocity error does)
        self.persist = self.frame_dt * min(PERSIST_FRAMES, max(1.0, 1.0 / (gamma * self.frame_dt)
                                                                if gamma > 0 else math.inf))
        self.history: list[np.ndarray] = []  # positions (N, 3) through the latest quiet frames
        self._systems: dict[int, System] = {}  # system_for's, by steps per frame
        self._systems_of: System | None = None  # the Simulation's System they derive from
        self.mpp: float | None = None  # metres per pixel at the cloth's nearest point
        self.state_dt = self.base.dt
        self.frame = 0
        self.asleep = False
        self.budget = budget_for(0.0, self.base.thickness)
        self.steps_used: list[int] = []  # accepted steps per simulated frame
        self.slept = 0
        self.rejected = 0
        self.steps_total = 0  # every step taken, estimates and redone frames included
        self.last_error_px = 0.0
        self.checked_at = 0  # the frame of the last error estimate
        self._started = False

    # --- the system at n steps per frame ---------------------------------------------------
    def system_for(self, n: int):
        """The System at n steps per frame, one object per n while the Simulation's System
        stays the same: numba types a System it has not seen in Python, about 0.6 ms a call
        (its ~60 arrays), against 0.07 ms for the same object (2026-11-26), and the stepping
        kernel is called every frame."""
        base = self.sim.system
        if self._systems_of is not base:
            self._systems, self._systems_of = {}, base
        system = self._systems.get(n)
        if system is None:
            dt = self.frame_dt / n
            damping = damping_at(self.base.damping, self.base.dt, dt)
            force_dt2 = dt * damping / self.gamma if self.gamma > 0 else dt * dt
            system = self._systems[n] = base._replace(dt=dt, damping=damping,
                                                      force_dt2=force_dt2, steps_per_frame=n)
        return system

    def _lag(self, dt: float) -> tuple[float, float]:
        """(E, G) with x(t - dt) = x - v E + a G for velocity v and constant acceleration a
        at x under the drag (v' = a - gamma v): E = (e^(gamma dt) - 1) / gamma, G = (E - dt)
        / gamma; dt and dt^2 / 2 without drag."""
        g = self.gamma
        if g * dt < 1e-6:
            return dt, 0.5 * dt * dt
        e = math.expm1(g * dt) / g
        return e, (e - dt) / g

    def _acceleration(self, system, t: float, v: np.ndarray) -> np.ndarray:
        state = self.sim._state
        force = np.zeros_like(state.x)
        total_force_now(state.x, v, t, system, force)
        a = force / system.mass
        a[:, system.pinned != 0] = 0.0
        return a

    def _verlet_velocity(self, system, dt: float, t: float) -> tuple[np.ndarray, np.ndarray]:
        """(v, a) at x of the Verlet state stepped at dt: a = F/m at x (forces seeing the
        step's velocity (x - x_last) / dt) and, with (E, G) = _lag(dt), v = (x - x_last + a G)
        / E (exact for a constant acceleration under the drag)."""
        state = self.sim._state
        a = self._acceleration(system, t, (state.x - state.last) / dt)
        e, g = self._lag(dt)
        return (state.x - state.last + a * g) / e, a

    def _set_step(self, system, t: float) -> None:
        """Give the Verlet state the step of `system`, keeping the velocity at x: with a = F/m
        at x and (E, G) = _lag, v = (x - x_last + a G_old) / E_old and x_last = x - v E + a G
        (exact for a constant acceleration under the drag; from rest on the first frame)."""
        state = self.sim._state
        if self.sim.integrator != "verlet":
            self.state_dt = system.dt
            self._started = True
            return
        old, new = self.state_dt, system.dt
        if self._started and old == new:
            return
        if self._started:
            v, a = self._verlet_velocity(system, old, t)
        else:
            v = np.zeros_like(state.x)
            a = self._acceleration(system, t, v)
        e_new, g_new = self._lag(new)
        free = system.pinned == 0
        state.last[:, free] = (state.x - v * e_new + a * g_new)[:, free]
        self.state_dt = new
        self._started = True

    # --- state snapshots -----------------------------------------------------------------
    def _save(self) -> dict:
        state = self.sim._state
        saved = {k: v.copy() for k, v in vars(state).items() if isinstance(v, np.ndarray)}
        reach = self.sim.system.reach
        saved["_reach"] = (reach.armed.copy(), reach.self_on.copy(),
                           self.sim.system.colliders.active.copy())
        saved["_dt"] = (self.state_dt, self._started)
        return saved

    def _restore(self, saved: dict) -> None:
        state = self.sim._state
        for k, v in saved.items():
            if not k.startswith("_"):
                np.copyto(getattr(state, k), v)
        reach = self.sim.system.reach
        armed, self_on, active = saved["_reach"]
        reach.armed[:], reach.self_on[:] = armed, self_on
        self.sim.system.colliders.active[:] = active
        self.state_dt, self._started = saved["_dt"]

    def _run(self, n: int) -> bool:
        """Advance the state over the frame in n steps; False if the guard tripped."""
        system = self.system_for(n)
        t0 = self.frame * self.frame_dt
        self._set_step(system, t0)
        done, kinetic, bound = self.sim._state.advance(system, n, self.frame * n)
        self.sim.make_contact_room()  # (a new System: system_for makes its own again)
        self.steps_total += done
        self._last_guard = (kinetic, bound, done, n)
        return done == n and kinetic <= bound and np.all(np.isfinite(self.sim._state.x))

    # --- one frame -------------------------------------------------------------------------
    def _estimate(self, n: int) -> tuple[bool, float]:
        """Run the frame with m = max(n // 2, floor) steps, restore, run it with n (kept):
        (both passed the guard, estimated error of the n-step result in pixels). The error
        compares where each result would put the points `persist` seconds later at its
        velocity: a velocity error shows for as long as the drag lets it last."""
        saved = self._save()
        m = max(n // 2, self.floor)
        ok = self._run(m)
        coarse = self._ahead(m)
        self._restore(saved)
        ok = self._run(n) and ok
        error = screen_distance(self.camera, self._ahead(n), coarse)
        return ok, error / ((n / m) ** self.order - 1.0)

    def _ahead(self, n: int) -> np.ndarray:
        """Positions (N, 3) `persist` seconds ahead at the state's velocity at x."""
        state, system = self.sim._state, self.system_for(n)
        t = (self.frame + 1) * self.frame_dt
        if self.sim.integrator == "verlet":  # (x - x_last) / dt lags by half a step
            v = self._verlet_velocity(system, system.dt, t)[0]
        else:
            v = state.velocity(system)
        return (state.x + v * self.persist).T

    def _arm_passes(self) -> None:
        """Arm pipeline.physics.reach when a premise it watched broke, or every REARM_EVERY frames
        (to find passes that can no longer act)."""
        system = self.sim.system
        reach = system.reach
        if not self.skip_passes:
            return
        if np.any(self.watched & (reach.armed == 0)):  # a premise broke: wait longer
            self.rearm_every = min(MAX_REARM_EVERY, 2 * self.rearm_every)
            self.watched[:] = 0
        if self.frame - self.armed_at < self.rearm_every:
            return
        held = bool(np.any(self.watched))  # the last arming's premises held all along
        new = arm(reach, system.colliders.active, self.sim._state.x, self.scene,
                  system.thickness, *self.budget, system.self_collision)
        self.sim.system = system._replace(reach=new)
        self.watched = new.armed.copy()
        self.armed_at = self.frame
        if not np.any(self.watched):  # nothing could be skipped: look again later
            self.rearm_every = min(MAX_REARM_EVERY, 2 * self.rearm_every)
        elif held:
            self.rearm_every = REARM_EVERY

    def advance_frame(self) -> None:
        """Advance one output frame (DivergenceError when no step count up to the maximum
        passes the guard)."""
        t0 = self.frame * self.frame_dt
        if self.asleep:
            wake = wake_time(self.scene, t0)
            if wake is None or wake >= t0 + self.frame_dt:
                self.frame += 1
                self.slept += 1
                return
            self.asleep = False
            self.check_every = 1  # check the first frame awake
        if not self.adaptive and not self.chaotic and self.pilot is None:
            self._run_pilot()
        if self.replay is not None:
            self._replay_frame()
            return
        self._arm_passes()
        start = self.sim._state.x.T.copy()
        target = self.safety * self.tolerance
        n = self.n
        checked = self.adaptive and self.since_check + 1 >= self.check_every
        redos = 0
        while True:
            saved = self._save()
            if checked:
                ok, error = self._estimate(n)
            else:
                ok, error = self._run(n), self.last_error_px
            if not ok:
                self._restore(saved)
                self.rejected += 1
                if 2 * n > self.n_max:
                    self._diverged(n)
                n, checked = 2 * n, self.adaptive
                continue
            if error <= target or redos >= MAX_REDOS or n >= self.n_max:
                break
            # too coarse: at most GROWTH times the steps at a time (a large jump in the step
            # count starts a transient of the stretch limit that itself reads as error)
            self._restore(saved)
            self.rejected += 1
            redos += 1
            n = min(self.n_max, max(n + 1, math.ceil(n * min(GROWTH, (error / target)
                                                             ** (1 / self.order)))))
        self.steps_used.append(n)
        if checked:
            rise = (error - self.last_error_px) / max(1, self.frame - self.checked_at)
            self.since_check = 0
            self.last_error_px, self.checked_at = error, self.frame
            self.n = self._next_steps(n, error / target)
            # check less often while far below the target (or below half of it at the fewest
            # steps, where a check can only ask for more), at once again when near it; at the
            # fewest steps and below the target, as long as the error's trend (its rise per
            # frame since the last check) stays below it
            grow = min(MAX_CHECK_EVERY, 2 * self.check_every)
            if error < (0.5 if n <= self.n_min else 0.25) * target:
                self.check_every = grow
            elif n <= self.n_min and error <= target:
                room = (target - error) / rise if rise > 0.0 else grow
                self.check_every = max(1, min(grow, math.floor(room)))
            else:
                self.check_every = 1
        else:
            self.since_check += 1
            self.n = n
        self.frame += 1
        self._after_frame(start)

    def _run_pilot(self) -> None:
        """Choose the classic model's steps per frame for the shot (module docstring, 1).
        The next pilot_seconds run at n1 and 2 n1 steps per frame side by side. Where their
        estimate wants at least 3 n1 steps, or more than both 2 n1 and the file's, a third
        run at that many (at least 3 n1, so that the check below can tell) checks that the
        error is first order: its distance from the 2 n1 run must be at most
        PILOT_CONVERGENCE times what first order predicts.
        Where it is not (the motion depends on the step chaotically), more steps buy no
        accuracy and the file's steps stay. A step count the guard rejects is doubled. The
        shot then goes on from a pilot run with enough steps where that costs no more than
        starting again (its frames are replayed), else starts again at the steps chosen."""
        frames = max(2, round(self.pilot_seconds / self.frame_dt))
        n1 = max(PILOT_STEPS, self.n_min)
        first, start = self.frame, self._save()
        while True:
            pair = self._pilot_runs((n1, 2 * n1), frames, first, start, None)
            if pair is not None:
                break
            self.rejected += 1
            if 4 * n1 > self.n_max:
                self._restore(start)
                self.frame = first
                self._diverged(2 * n1)
            n1 *= 2
        d1, kept, runs = pair
        del pair  # its runs' frames are held by `runs` alone
        constant = 2.0 * n1 * d1  # the error of n steps per frame: constant / n pixels
        want = self._pilot_steps(constant)
        file_steps = self._clamp(self.scene.simulation.steps_per_frame)
        steps, converges = (n1, 2 * n1), None
        if want >= 3 * n1 or want > max(2 * n1, file_steps):
            runs = {}  # the shot goes on from the third run or starts again at the file's
            n3 = min(self.n_max, max(want, 3 * n1))
            third = self._pilot_runs((n3,), frames, first, start, kept)
            d2 = third[0] if third is not None else math.inf
            converges = d2 <= PILOT_CONVERGENCE * d1 * (1.0 - 2.0 * n1 / n3)
            steps = (n1, 2 * n1, n3)
            if converges:
                constant = d2 / (0.5 / n1 - 1.0 / n3)
                want, runs = self._pilot_steps(constant), third[2]
                if want <= PILOT_SLACK * n3:  # within the estimate's own spread: keep n3
                    want = min(want, n3)
            else:
                want, runs = file_steps, {}
        self._restore(start)
        self.frame = first
        self.n = want
        self.replay, self.replay_first = self._pilot_reuse(runs, want, frames), first
        if self.replay is not None:
            self.n = self.replay[0]
        self.pilot = {"steps": steps, "seconds": frames * self.frame_dt, "distance_px": d1,
                      "converges": converges, "constant_px": constant,
                      "predicted_px": None if converges is False else constant / self.n,
                      "reused": self.replay is not None}

    def _pilot_steps(self, constant: float) -> int:
        """The fewest steps per frame that bring constant / n to PILOT_TARGET tolerances."""
        return self._clamp(math.ceil(constant / (PILOT_TARGET * self.tolerance)))

    def _clamp(self, n: int) -> int:
        """n steps per frame within [n_min, n_max]."""
        return int(min(self.n_max, max(self.n_min, n)))

    def _pilot_reuse(self, runs: dict, want: int, frames: int) -> tuple | None:
        """(n, frames, end state) of the pilot run the shot goes on from: of the runs with at
        least `want` steps whose remaining frames cost no more than the whole shot at `want`
        (an unknown shot length counts as endless), the cheapest, and of equals the finest
        (a pilot that covered the whole shot gives its finest run for free); or None to
        start again."""
        if not self.shot_seconds:
            return (want, *runs[want]) if want in runs else None
        shot = round(self.shot_seconds / self.frame_dt)
        left = max(0, shot - frames)
        fits = [n for n in runs if n >= want and n * left <= want * shot]
        if not fits:
            return None
        n = min(fits, key=lambda m: (m * left, -m))
        return (n, *runs[n])

    def _pilot_runs(self, levels: tuple, frames: int, first: int, start: dict,
                    against: list | None) -> tuple[float, list, dict] | None:
        """Run the pilot's frames from `start` at each of `levels` steps per frame side by
        side: (the largest screen distance over the second half of the frames between the
        first two levels, or between the first and `against` (positions kept from an earlier
        run), the second level's positions there as float32, and per level its frames'
        positions and velocity state and its end state: none past REPLAY_BYTES), or None
        when the guard rejected a step."""
        states = [start] * len(levels)
        records: list[list] = [[] for _ in levels]
        state = self.sim._state
        keep = frames * len(levels) * sum(getattr(state, k).nbytes for k in REPLAYED) \
            <= REPLAY_BYTES
        kept, worst, j = [], 0.0, 0
        for f in range(frames):
            x = []
            for k, steps in enumerate(levels):
                self._restore(states[k])
                self.frame = first + f
                if not self._run(steps):
                    return None
                states[k] = self._save()
                if keep:
                    records[k].append({key: states[k][key] for key in REPLAYED})
                x.append(self.sim._state.x.T.copy())
            if 2 * f < frames:  # the second half: the swing after the release
                continue
            other = against[j] if against is not None else x[1]
            j += 1
            worst = max(worst, screen_distance(self.camera, x[0], other))
            if against is None:
                kept.append(x[1].astype(np.float32))
        return worst, kept, ({n: (records[k], states[k]) for k, n in enumerate(levels)}
                             if keep else {})

    def replay_from_start(self, records: list) -> None:
        """Go back to frame 0, replay `records` (the REPLAYED state after each frame this
        stepper has run, from the start), then go on from where it is: pipeline.fidelity.fem_grid
        hands a pilot grid's run over to the shot so."""
        self.replay = (self.steps_used, records, self._save())
        self.replay_first = self.frame = self.slept = 0
        self.steps_used, self.history, self.asleep = [], [], False

    def _replay_frame(self) -> None:
        """The next frame of the pilot run the shot goes on from, as that run left it."""
        n, records, end = self.replay  # n: steps per frame, or a list of them per frame
        state, k = self.sim._state, self.frame - self.replay_first
        start = state.x.T.copy()
        for key in REPLAYED:
            np.copyto(getattr(state, key), records[k][key])
        if k + 1 == len(records):
            self._restore(end)
            self.replay = None
        self.steps_used.append(n[k] if isinstance(n, list) else n)
        self.frame += 1
        self._after_frame(start)
        if self.asleep:  # asleep here, as a shot started again at n would be: stay here
            self.replay = None

    def _next_steps(self, n: int, ratio: float) -> int:
        """The next frame's steps from this one's error ratio (error / target): up if above
        1, down where below half of it to where it would be half (hysteresis), by at most
        GROWTH either way."""
        if ratio > 1.0:
            want = math.ceil(n * min(GROWTH, ratio ** (1 / self.order)))
        elif ratio < 0.5:
            want = math.floor(n / min(GROWTH, max(1.0, (0.5 / max(ratio, 1e-9))
                                                  ** (1 / self.order))))
        else:
            want = n
        return self._clamp(want)

    def _after_frame(self, start: np.ndarray) -> None:
        """The motion budget of the next arming, and the sleep test: positions are kept only
        through a run of quiet frames."""
        x = self.sim._state.x.T
        diff = x - start
        moved_m = math.sqrt(float(np.max(np.einsum("ij,ij->i", diff, diff)))) if len(x) else 0.0
        self.budget = budget_for(moved_m, self.sim.system.thickness)
        t = self.frame * self.frame_dt
        if gusty(self.scene):  # never sleeps
            return
        if self.frame % REARM_EVERY == 1 or self.mpp is None:  # changes slowly
            self.mpp = metres_per_pixel(self.camera, x)
        # an upper bound in pixels: metres over metres per pixel at the nearest point
        if moved_m / self.mpp >= SLEEP_FRACTION * self.tolerance:
            self.history.clear()
            return
        if not self.history:
            self.history.append(start)
        self.history.append(x.copy())
        window = 3 * max(1, round(SLEEP_TIME / self.frame_dt / 3))
        del self.history[:-window - 1]
        if len(self.history) > window and self._at_rest(window) and wake_time(self.scene, t) != t:
            self.asleep = True
            self.history.clear()

    def _at_rest(self, window: int) -> bool:
        """The last `window` frames were quiet (no point moved SLEEP_FRACTION of the
        tolerance in a frame) and the drift of their mean positions, extrapolated, stays
        below SLEEP_DRIFT of the tolerance. Means over the window's thirds average out jitter
        in place (contact and the stretch limit keep some points trembling forever); with
        d1, d2 the largest moves of a point's mean from one third to the next, the drift
        left is d2 r / (1 - r) for a decay r = d2 / d1 < 1 per third, else d2 times the
        thirds in SLEEP_HORIZON. A swing through a turning point does not decay."""
        third = window // 3
        means = [np.mean(self.history[1 + k * third:1 + (k + 1) * third], axis=0)
                 for k in range(3)]
        scale = 1.0 / self.mpp
        d1 = float(np.max(np.linalg.norm(means[1] - means[0], axis=1))) * scale
        d2 = float(np.max(np.linalg.norm(means[2] - means[1], axis=1))) * scale
        if d2 < d1:
            remaining = d2 * (d2 / d1) / (1.0 - d2 / d1)
        else:
            remaining = d2 * SLEEP_HORIZON / (third * self.frame_dt)
        return remaining < SLEEP_DRIFT * self.tolerance

    def _diverged(self, n: int) -> None:
        from pipeline.physics.errors import DivergenceError

        kinetic, bound, done, steps = self._last_guard
        raise DivergenceError(
            f"simulation diverged at frame {self.frame + 1} (t = {self.frame * self.frame_dt:.4f}"
            f" s) under fidelity auto: the divergence guard rejected {n} steps per frame "
            f"(step {done} of {steps}: kinetic energy {kinetic:.4g} J, bound {bound:.4g} J), "
            f"the most auto allows ({self.n_max}); the scene is unstable at any step: check "
            "cloth.ks / cloth.fem and the colliders")

    # --- reporting -------------------------------------------------------------------------
    @property
    def skipped_collider_steps(self) -> int:
        """Steps on which at least one collider was skipped."""
        return int(self.sim.system.reach.counts[2])

    def summary(self) -> dict:
        """What was used: steps per frame min / median / max (simulated frames), frames
        slept, frames redone, steps taken in all, self-collision passes run."""
        used = self.steps_used or [0]
        counts = self.sim.system.reach.counts
        return {"steps_per_frame_min": int(min(used)), "steps_per_frame_median":
                float(np.median(used)), "steps_per_frame_max": int(max(used)),
                "frames_simulated": len(self.steps_used), "frames_slept": self.slept,
                "frames_redone": self.rejected, "steps_total": self.steps_total,
                "self_collision_passes": int(counts[1]) if self.sim.system.self_collision else 0,
                "steps_with_a_collider_skipped": int(counts[2]), "pilot": self.pilot,
                "grid": None if self.grid is None else self.grid.as_dict()}

    def summary_text(self) -> str:
        s = self.summary()
        pilot = "" if self.pilot is None else pilot_text(self.pilot) + ", "
        if self.grid is not None:
            pilot = self.grid.text() + ", " + pilot
        return (f"auto: {pilot}steps/frame {s['steps_per_frame_min']}/"
                f"{s['steps_per_frame_median']:g}/"
                f"{s['steps_per_frame_max']} (min/median/max), {s['frames_slept']} frames slept, "
                f"{s['frames_redone']} redone, {s['steps_total']} steps in all, "
                f"{s['self_collision_passes']} self-collision passes, colliders skipped on "
                f"{s['steps_with_a_collider_skipped']} steps")


def pilot_text(pilot: dict) -> str:
    """The classic pilot's figures in a few words."""
    steps = "/".join(str(n) for n in pilot["steps"])
    if pilot["converges"] is False:
        result = "not converging in the step (chaotic motion): the file's steps"
    else:
        result = (f"predicted largest error {pilot['predicted_px']:.2g} px (aim: "
                  f"{PILOT_TARGET:g} x tolerance)")
    reused = ", the shot goes on from its run" if pilot["reused"] else ""
    return f"pilot {steps} steps/frame over {pilot['seconds']:.3g} s: {result}{reused}"


"""Classical fourth-order Runge-Kutta on (x, v) with a(x, v) = F(x, v, t) / m - gamma v
(gamma = system.drag_rate: the scene's damping as a drag; see docs/integrators.md).

Four force evaluations per step; the position passes (self-collision, colliders, Provot)
run once, after the full step; their correction dx of a point becomes a velocity change
v' += dx / dt (docs/integrators.md).
Pinned points never move and keep v = 0.
State: positions x, velocities v, start-of-step positions last (3, N) each, plus scratch.
"""
from __future__ import annotations

import numpy as np

from clothjit import KernelPointer, njit, prange

from ..forces import CHUNKS, _chunk, total_force
from ..system import System, corrected_velocities, drag_rate, position_passes, step_guard
from .euler import VelocityState

NAME = "rk4"
CONDITIONALLY_STABLE = True


class State(VelocityState):
    """VelocityState with the stages' scratch, and the stage and the final update kernels
    through pointers (compiled once, on their own, not again in every stepping kernel: see
    clothjit.KernelPointer)."""

    def __init__(self, system: System) -> None:
        super().__init__(system)
        self.stage_x = np.zeros_like(self.x)
        self.stage_v = np.zeros_like(self.x)
        self.sum_x = np.zeros_like(self.x)
        self.sum_v = np.zeros_like(self.x)
        self.stage = KernelPointer(_stage, (
            self.x, self.v, self.stage_x, self.stage_v, self.sum_x, self.sum_v, self.force,
            system.pinned, system.mass, 0.0, 0.0, 0.0))
        self.finish = KernelPointer(_finish, (self.x, self.v, self.last, self.sum_x, self.sum_v,
                                              system.pinned, 0.0, self.predicted))

    def arguments(self, system: System, steps: int, first_step: int) -> tuple:
        """The stepping kernel's arguments."""
        return (system, self.x, self.v, self.last, self.predicted, self.force, self.stage_x,
                self.stage_v, self.sum_x, self.sum_v, self.stage, self.finish, steps,
                first_step)

    def advance(self, system: System, steps: int, first_step: int) -> tuple[int, float, float]:
        return advance(*self.arguments(system, steps, first_step))


@njit(cache=True, nogil=True, parallel=True, no_cpython_wrapper=True, pointer=True)
def _stage(x, v, stage_x, stage_v, sum_x, sum_v, force, pinned, mass, gamma, weight, step):
    """Add weight * (stage velocity, stage acceleration) to the sums and, if step > 0, set
    the next stage to (x, v) + step * (that velocity, that acceleration)."""
    n = x.shape[1]
    for c in prange(CHUNKS):
        lo, hi = _chunk(c, n)
        for p in range(lo, hi):
            if pinned[p]:
                continue
            for a in range(3):
                kv = stage_v[a, p]
                ka = force[a, p] / mass[p] - gamma * kv
                sum_x[a, p] += weight * kv
                sum_v[a, p] += weight * ka
                if step > 0.0:
                    stage_x[a, p] = x[a, p] + step * kv
                    stage_v[a, p] = v[a, p] + step * ka


@njit(cache=True, nogil=True, parallel=True, no_cpython_wrapper=True, pointer=True)
def _finish(x, v, last, sum_x, sum_v, pinned, dt, predicted):
    n = x.shape[1]
    for c in prange(CHUNKS):
        lo, hi = _chunk(c, n)
        for p in range(lo, hi):
            for a in range(3):
                last[a, p] = x[a, p]
                if not pinned[p]:
                    x[a, p] += (dt / 6.0) * sum_x[a, p]
                    v[a, p] += (dt / 6.0) * sum_v[a, p]
                predicted[a, p] = x[a, p]


@njit(cache=True, nogil=True)
def advance(s, x, v, last, predicted, force, stage_x, stage_v, sum_x, sum_v, stage, finish,
            steps, first_step):
    """Run `steps` steps; returns (steps done, kinetic energy, bound) like verlet.advance."""
    gamma = drag_rate(s)
    h = s.dt
    kinetic = bound = 0.0
    for step in range(steps):
        t = (first_step + step) * h
        # element by element: an array-to-array slice assignment makes numba compile its
        # shape-mismatch error message (string formatting, ~3.7 s of a first rk4 compile)
        for a in range(3):
            for p in range(x.shape[1]):
                stage_x[a, p] = x[a, p]
                stage_v[a, p] = v[a, p]
                sum_x[a, p] = 0.0
                sum_v[a, p] = 0.0
        # (weight of the stage, step to the next stage, time of this stage)
        for weight, next_step, at in ((1.0, 0.5 * h, 0.0), (2.0, 0.5 * h, 0.5 * h),
                                      (2.0, h, 0.5 * h), (1.0, 0.0, h)):
            total_force(stage_x, stage_v, t + at, s, force)
            stage(x, v, stage_x, stage_v, sum_x, sum_v, force, s.pinned, s.mass, gamma,
                  weight, next_step)
        finish(x, v, last, sum_x, sum_v, s.pinned, h, predicted)
        position_passes(x, last, s, t)
        corrected_velocities(x, predicted, v, s.pinned, h)
        ok, kinetic, bound = step_guard(x, last, s)
        if not ok:
            return step + 1, kinetic, bound
    return steps, kinetic, bound

"""Verlet with damping, the classic model's integrator (SPEC section 2), exactly as the course.

x' = x + (1 - damping) (x - x_last) + (F / m) dt^2; pinned points never move.
State: positions x and last positions x_last, both (3, N).
"""
from __future__ import annotations

import numpy as np
from numba import njit, prange

from ..colliders import collide_all, collide_point
from ..constraints import limit_stretch
from ..forces import CHUNKS, _chunk, compute_spring_forces, gathered_force
from ..self_collision import self_collide
from ..system import System, energy_guard, motion_summary

NAME = "verlet"
CONDITIONALLY_STABLE = True


class State:
    """Positions and last positions, (3, N) each."""

    def __init__(self, system: System) -> None:
        self.x = system.x0.copy()
        self.last = system.x0.copy()

    def velocity(self, system: System) -> np.ndarray:
        return (self.x - self.last) / system.dt

    def advance(self, system: System, steps: int) -> tuple[int, float, float]:
        return advance(system, self.x, self.last, steps)


@njit(cache=True, nogil=True, parallel=True)
def _forces_and_update(x, last, pinned, spring_force, offsets, order, weight, mass, keep, dt2,
                       kinds, params):
    """Gather forces and take the Verlet step for every free point, then apply the colliders
    `kinds`/`params` to it (pass empty ones when a self-collision pass must come between)."""
    n = x.shape[1]
    for c in prange(CHUNKS):
        lo, hi = _chunk(c, n)
        for p in range(lo, hi):
            if pinned[p]:
                continue
            for a in range(3):
                force = gathered_force(p, a, weight[a], spring_force, offsets, order)
                xa = x[a, p]
                x[a, p] = xa + keep * (xa - last[a, p]) + (force / mass) * dt2
                last[a, p] = xa
            x[0, p], x[1, p], x[2, p] = collide_point(
                kinds, params, x[0, p], x[1, p], x[2, p], last[0, p], last[1, p], last[2, p])


@njit(cache=True, nogil=True)
def advance(s, x, last, steps):
    """Run `steps` steps. Returns (steps done, kinetic energy, bound); fewer steps than asked
    means the divergence guard tripped after the last one (see system.energy_guard)."""
    keep = 1.0 - s.damping
    dt2 = s.dt * s.dt
    weight = s.mass * s.gravity
    # colliders go with the update unless self-collision must come between
    fused_kinds = s.collider_kinds[:0] if s.self_collision else s.collider_kinds
    kinetic = bound = 0.0
    for step in range(steps):
        compute_spring_forces(x, s.offsets, s.exists, s.rest, s.stiffness, s.spring_force)
        _forces_and_update(x, last, s.pinned, s.spring_force, s.offsets, s.gather_order,
                           weight, s.mass, keep, dt2, fused_kinds, s.collider_params)
        if s.self_collision:
            self_collide(x, s.pinned, s.width, s.height, s.nw, s.nh, s.thickness,
                         s.steps_per_frame, s.scratch)
            collide_all(x, last, s.pinned, s.collider_kinds, s.collider_params)
        limit_stretch(x, s.offsets, s.exist_bits, s.limit, s.limit_sq_lo, s.pinned, s.mask)
        finite, v_sq, drop = motion_summary(x, last, s)
        kinetic, bound = energy_guard(v_sq / dt2, drop, s)
        if not finite or not kinetic <= bound:
            return step + 1, kinetic, bound
    return steps, kinetic, bound

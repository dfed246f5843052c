"""Explicit (forward) Euler on positions and velocities; its kernel also serves
symplectic Euler (pipeline/physics/integrators/symplectic_euler.py), which differs in one line.

    a = F(x, v, t) / m - gamma v      (gamma = system.drag_rate: the scene's damping)
    explicit:    x' = x + dt v,  v' = v + dt a
    symplectic:  v' = v + dt a,  x' = x + dt v'
Pinned points never move and keep v = 0. After the update come the shared position passes
(self-collision, colliders, Provot); their correction dx of a point becomes a velocity
change v' += dx / dt (docs/integrators.md).
State: positions x, velocities v, start-of-step positions last, all (3, N).
"""
from __future__ import annotations

import numpy as np

from clothjit import KernelPointer, njit

from ..forces import total_force
from ..system import System, corrected_velocities, drag_rate, position_passes, step_guard

NAME = "euler"
CONDITIONALLY_STABLE = True


class VelocityState:
    """Positions, velocities and start-of-step positions (3, N) each, plus scratch."""

    def __init__(self, system: System) -> None:
        self.x = system.x0.copy()
        self.v = np.zeros_like(self.x)
        self.last = system.x0.copy()
        self.predicted = np.zeros_like(self.x)
        self.force = np.zeros_like(self.x)

    def velocity(self, system: System) -> np.ndarray:
        return self.v.copy()


class State(VelocityState):
    """Explicit Euler's (symplectic Euler's with `symplectic`), with the update of the
    points through a pointer (compiled once, on its own, not again in every stepping
    kernel: see clothjit.KernelPointer)."""

    symplectic = False

    def __init__(self, system: System) -> None:
        super().__init__(system)
        self.update = KernelPointer(euler_update, (
            self.x, self.v, self.last, self.force, system.pinned, system.mass, 0.0, 0.0,
            self.symplectic, self.predicted))

    def arguments(self, system: System, steps: int, first_step: int) -> tuple:
        """The stepping kernel's arguments."""
        return (system, self.x, self.v, self.last, self.predicted, self.force, self.update,
                steps, first_step, self.symplectic)

    def advance(self, system: System, steps: int, first_step: int) -> tuple[int, float, float]:
        return advance(*self.arguments(system, steps, first_step))


@njit(cache=True, nogil=True, error_model="numpy", no_cpython_wrapper=True, pointer=True)
def euler_update(x, v, last, force, pinned, mass, gamma, dt, symplectic, predicted):
    """The step of every point; pinned points keep x and v. Serial: LLVM vectorises the loop
    (pins are selects), 6 us for 2500 points against 17-19 us for a parallel loop over
    chunks, 89-93 us for 40,000 against 158-174 us; a serial kernel also compiles sooner."""
    for a in range(3):
        for p in range(x.shape[1]):
            xi = x[a, p]
            vi = v[a, p]
            last[a, p] = xi
            acc = force[a, p] / mass[p] - gamma * vi
            if symplectic:
                vn = vi + dt * acc
                xn = xi + dt * vn
            else:
                xn = xi + dt * vi
                vn = vi + dt * acc
            free = pinned[p] == 0
            x[a, p] = xn if free else xi
            v[a, p] = vn if free else vi
            predicted[a, p] = xn if free else xi


@njit(cache=True, nogil=True)
def advance(s, x, v, last, predicted, force, update, steps, first_step, symplectic):
    """Run `steps` steps; returns (steps done, kinetic energy, bound) like verlet.advance."""
    gamma = drag_rate(s)
    kinetic = bound = 0.0
    for step in range(steps):
        t = (first_step + step) * s.dt
        total_force(x, v, t, s, force)
        update(x, v, last, force, s.pinned, s.mass, gamma, s.dt, symplectic, predicted)
        position_passes(x, last, s, t)
        corrected_velocities(x, predicted, v, s.pinned, s.dt)
        ok, kinetic, bound = step_guard(x, last, s)
        if not ok:
            return step + 1, kinetic, bound
    return steps, kinetic, bound

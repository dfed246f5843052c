"""Integrators: one module each, same interface.

A module defines NAME, CONDITIONALLY_STABLE (True when its step must stay below the explicit
stability limit of the lattice: the Simulation then warns above it) and a `State(system)`
class with `x` (3, N) positions, `velocity(system)`,
`advance(system, steps, first_step) -> (steps done, kinetic energy, bound)`, where fewer
steps done than asked means the divergence guard tripped, and `arguments(system, steps,
first_step)`, what `advance` passes to the module's numba kernel `advance` (a first run
compiles it from their types: pipeline.run.warmup). Modules are found by name:
`state_class("verlet")` imports `pipeline.physics.integrators.verlet` ('-' becomes '_':
`state_class("implicit-euler")` imports `pipeline.physics.integrators.implicit_euler`).

    verlet            the classic damped Verlet (SPEC section 2), bit-identical to the course
    euler             explicit Euler on (x, v)
    symplectic-euler  v first, then x with the new v (shares euler's kernel)
    rk4               classical Runge-Kutta, four force evaluations per step
    implicit-euler    backward Euler linearised once per step, matrix-free PCG (Baraff and
                      Witkin 1998), pinned points filtered
    xpbd              springs as compliant distance constraints, alpha = 1 / k (Macklin et al.
                      2016), one Gauss-Seidel sweep per step
    vbd               Vertex Block Descent (Chen et al. 2024): backward Euler by per-point
                      3x3 Newton steps on its incremental potential, colour by colour,
                      simulation.iterations sweeps per step; Provot's limit off

All of them use the same forces (forces.total_force), the same position passes in the
classic order after the update (system.position_passes: self-collision, colliders, Provot)
and the same divergence guard (system.step_guard). The velocity-based methods read the
scene's damping as a drag rate (system.drag_rate) and turn the position passes' corrections
into velocity changes (system.corrected_velocities). docs/integrators.md has the measured
orders, stability limits and work-precision charts, and which one to pick.
"""
from __future__ import annotations

import importlib
import sys
from types import ModuleType

from pipeline.scene import INTEGRATORS


def integrator_module(name: str) -> ModuleType:
    """The module of the integrator called `name` (as in the scene)."""
    if name not in INTEGRATORS:
        raise ValueError(f"unknown integrator {name!r}; expected one of {', '.join(INTEGRATORS)}")
    return importlib.import_module(f"{__name__}.{name.replace('-', '_')}")


def state_class(name: str):
    """The State class of the integrator called `name` (as in the scene)."""
    return integrator_module(name).State


def stepping_kernel(name: str):
    """The numba kernel that steps a scene with the integrator called `name`: the `advance`
    of the module that defines its State's advance (symplectic Euler shares Euler's)."""
    return sys.modules[state_class(name).advance.__module__].advance

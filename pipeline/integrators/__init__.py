"""Integrators: one module each, same interface.

A module defines NAME and a `State(system)` class with `x` (3, N) positions,
`velocity(system)` and `advance(system, steps) -> (steps done, kinetic energy, bound)`,
where fewer steps done than asked means the divergence guard tripped. Modules are found by
name: `state_class("verlet")` imports `pipeline.integrators.verlet`.
"""
from __future__ import annotations

import importlib

from ..scene import INTEGRATORS


def state_class(name: str):
    """The State class of the integrator called `name` (as in the scene)."""
    if name not in INTEGRATORS:
        raise ValueError(f"unknown integrator {name!r}; expected one of {', '.join(INTEGRATORS)}")
    module = importlib.import_module(f"{__name__}.{name.replace('-', '_')}")
    return module.State

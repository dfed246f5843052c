"""Cloth animation pipeline: scenes, the classic cloth simulator, frame assembly, the CLI.

`load_scene` is light (no numba); the simulator is imported on first use.
"""
from __future__ import annotations

from typing import Any

from .scene import Scene, SceneError, load_scene

__all__ = ["Scene", "SceneError", "load_scene", "Simulation", "simulate", "DivergenceError",
           "StabilityWarning"]
__version__ = "0.1.0"

_SIMULATION_NAMES = {"Simulation", "simulate", "DivergenceError", "StabilityWarning"}


def __getattr__(name: str) -> Any:
    if name in _SIMULATION_NAMES:
        from . import simulation

        return getattr(simulation, name)
    raise AttributeError(f"module 'pipeline' has no attribute {name!r}")

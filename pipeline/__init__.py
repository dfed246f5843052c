"""Cloth animation pipeline: scenes, the classic cloth simulator, frame assembly, the CLI."""
from .scene import Scene, SceneError, load_scene
from .simulation import DivergenceError, Simulation, StabilityWarning, simulate

__all__ = ["Scene", "SceneError", "load_scene", "Simulation", "simulate", "DivergenceError",
           "StabilityWarning"]
__version__ = "0.1.0"

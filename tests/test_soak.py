"""Soak (not in the default run; `pytest -m soak`): every shipped scene, with its own
integrator, for 30 s of simulated time, in a fresh process (benchmarks/soak.py --one):
no divergence, and memory does not keep growing."""
from __future__ import annotations

import json
import subprocess
import sys

import pytest

from conftest import ROOT, SCENES

pytestmark = pytest.mark.soak


@pytest.mark.parametrize("name", sorted(p.stem for p in SCENES.glob("*.json")))
def test_scene_runs_30_seconds(name):
    scene = json.loads((SCENES / f"{name}.json").read_text())
    integrator = scene.get("simulation", {}).get("integrator", "verlet")
    r = subprocess.run([sys.executable, str(ROOT / "benchmarks" / "soak.py"), "--seconds", "30",
                        "--one", str(SCENES / f"{name}.json"), integrator],
                       capture_output=True, text=True, timeout=3600)
    assert r.returncode == 0, r.stderr
    result = json.loads(r.stdout.strip().splitlines()[-1])
    assert result["diverged"] is None, result["diverged"]
    assert result["frames_done"] == result["frames"]
    assert result["rss_growth_mb"] < 50, result

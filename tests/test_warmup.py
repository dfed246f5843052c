"""The first run on a machine (pipeline/warmup.py): an empty numba cache is filled by
render and its compile helper together, the output is the same as a warm run's, and the
next run finds every kernel cached."""
from __future__ import annotations

import io
import json
import re
import subprocess
import sys
from pathlib import Path
from types import SimpleNamespace

import pytest

from conftest import cloth_dict, scene_dict

from pipeline import warmup

#: the folder holding the package these tests import
HOME = Path(warmup.__file__).resolve().parents[1]
SCENE = scene_dict(cloth_dict(10, 10, thickness=0.0095, damping=0.2, density=150.0, ks=5000.0),
                   spheres=[((0.5, 0.2, 0.5), 0.2, 0.3)])


def _render(scene: Path, out: Path, cache: Path, cwd: Path) -> str:
    """`render` as an installed command runs it: the package these tests import (installed,
    or the tree), started in `cwd`."""
    env = {"PATH": "/usr/bin:/bin", "NUMBA_CACHE_DIR": str(cache)}
    code = f"import sys; sys.path.insert(0, {str(HOME)!r}); from pipeline.cli import main; " \
           "sys.exit(main())"
    r = subprocess.run([sys.executable, "-c", code, str(scene), "--out", str(out),
                        "--size", "24x24", "--duration", "0.2"], env=env, cwd=cwd,
                       capture_output=True, text=True, timeout=900)
    assert r.returncode == 0, r.stderr
    return r.stderr.strip().splitlines()[-1]


def test_cold_run_fills_the_cache_for_the_next_run(tmp_path):
    scene = tmp_path / "s.json"
    scene.write_text(json.dumps(SCENE))
    cache = tmp_path / "numba"
    # started in a folder holding another `pipeline` (a user's clone beside the installed
    # package): the compile helper must import the package render runs, not this one
    decoy = tmp_path / "work" / "pipeline"
    decoy.mkdir(parents=True)
    marker = tmp_path / "decoy-imported"
    (decoy / "__init__.py").write_text(f"open({str(marker)!r}, 'w').close()\n"
                                       "raise ImportError('the decoy package')\n")
    (decoy / "warmup.py").write_text("")
    cold = _render(scene, tmp_path / "cold.gif", cache, decoy.parent)
    assert not marker.exists(), "the compile helper imported the working folder's pipeline"
    assert re.search(r"; compile [\d.]+ s, simulate", cold), cold
    # the helper's share (forces, the renderer's fragment stage) and this process's share
    # (colliders) are all in the one cache
    names = {p.name.split("-")[0] for p in cache.rglob("*.nbi")}
    assert {"forces.internal_forces", "__init__.collide_all", "shade._fragment_stage",
            "verlet.advance"} <= names, sorted(names)
    warm = _render(scene, tmp_path / "warm.gif", cache, decoy.parent)
    assert "compile" not in warm, warm
    assert (tmp_path / "cold.gif").read_bytes() == (tmp_path / "warm.gif").read_bytes()


# never in one scene's jobs: a table has the mesh's projection or its stand-in; the FEM has
# no stretch limit
EXCLUSIVE = [{"pipeline.colliders.mesh:project", "pipeline.colliders:_unmoved"},
             {"pipeline.fem:_band", "pipeline.constraints:limit_stretch"}]


def test_split_balances_the_two_processes():
    names = list(warmup.COMPILE_SECONDS)
    for mask in range(1, 2 ** len(names)):
        chosen_names = {n for k, n in enumerate(names) if mask >> k & 1}
        if any(pair <= chosen_names for pair in EXCLUSIVE):
            continue
        jobs = sorted((warmup.Job(n, ()) for n in sorted(chosen_names)),
                      key=lambda j: -warmup.COMPILE_SECONDS[j.name])
        for render in (False, True):
            for step in (False, True):
                here, helper, two = warmup.split(jobs, render, step)
                assert sorted(j.name for j in here + helper) == sorted(j.name for j in jobs)
                alone = warmup.estimate_seconds(jobs, [], render, step, False)
                best = min(warmup.estimate_seconds(
                    [j for k, j in enumerate(jobs) if side >> k & 1],
                    [j for k, j in enumerate(jobs) if not side >> k & 1], render, step, True)
                    for side in range(2 ** len(jobs)))
                chosen = warmup.estimate_seconds(here, helper, render, step, two)
                # the helper only when it is faster than one process
                assert chosen <= alone and (two or not helper)
                # longest first to the side that ends sooner: near the best split
                assert chosen <= min(alone, best * 4 / 3) + 1e-9
    # the README scene: the renderer and every simulation kernel cold -> two processes
    jobs = [warmup.Job(n, ()) for n in names if n != "pipeline.self_collision:self_collide"
            and n != "pipeline.wind:add_wind_force"]
    assert warmup.split(jobs, True, True)[2]
    # one small kernel and nothing else: compiled here
    assert warmup.split([warmup.Job("pipeline.system:energy_guard", ())], False, False) == (
        [warmup.Job("pipeline.system:energy_guard", ())], [], False)


class _Counted:
    """A stand-in for the progress bar: its total and the updates it got."""

    def __init__(self, total, *args):
        self.total, self.done = total, 0

    def update(self, n):
        self.done += n

    def close(self):
        pass


class _Job(warmup.Job):
    def cached(self):
        return False

    def compile(self):
        pass


class _Helper:
    """A stand-in for the compile helper's process: it reports one kernel, then the end of
    its simulation share."""

    def __init__(self, *args, **kwargs):
        self.stdin = io.BytesIO()
        self.stdout = io.BytesIO(b"b\n" + warmup.SIMULATION_DONE + b"\n")

    def wait(self):
        return 0

    def kill(self):
        pass


@pytest.mark.parametrize("step", [False, True])
def test_the_bar_counts_each_kernel_compiled_once(monkeypatch, step):
    """The bar's total is what gets compiled: in two processes too, the stepping kernel
    counts only when it is not cached (it was always counted: the bar overshot)."""
    bars, stepped = [], []
    monkeypatch.setattr(warmup, "bar", lambda *a: bars.append(_Counted(*a)) or bars[-1])
    monkeypatch.setattr(warmup, "sim_jobs", lambda system: [_Job("a", ()), _Job("b", ())])
    monkeypatch.setattr(warmup, "_stepping_cached", lambda sim: not step)
    monkeypatch.setattr(warmup, "split", lambda jobs, render, step: (jobs[:1], jobs[1:], True))
    monkeypatch.setattr(warmup.subprocess, "Popen", _Helper)
    sim = SimpleNamespace(system=None, compile_kernels=lambda: stepped.append(1))
    warmup.warm_up(sim, None)
    assert bars[0].total == 2 + step and bars[0].done == bars[0].total
    assert len(stepped) == step


def test_compiles_before_the_warm_up_are_said_counted_and_timed(monkeypatch):
    """A compile while the Simulation is built (a FEM cloth's stability limit) says the
    first-run message once, counts each kernel (callee included) and is timed; kernels
    already compiled say and count nothing."""
    from numba import njit

    @njit  # not cached: compiled in this test whatever numba's cache holds
    def inner(a):
        return max(a, 0.5) * 2.0  # max: numba compiles its own overload too (not counted)

    @njit
    def outer(a):
        return inner(a) + 1.0

    said = []
    counted = _Counted(None)
    monkeypatch.setattr(warmup, "counter", lambda *a: counted)
    monkeypatch.setattr(warmup, "OURS", (__name__.split(".")[0],))  # this file's kernels
    with warmup.CompileWatch(said.append, True) as watch:
        assert outer(1.0) == 3.0
    assert said == [warmup.FIRST_RUN.format("")]
    assert watch.said and watch.seconds > 0.0
    assert counted.done == 2  # outer, and inner compiled while typing it: not numba's max
    with warmup.CompileWatch(said.append, True) as again:
        assert outer(2.0) == 5.0
    assert len(said) == 1 and not again.said and again.seconds == 0.0

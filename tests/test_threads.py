"""numba's threads from the free cores (clothjit.THREADS): real CPU-bound processes beside
a real child process, the settings that override the choice, and a bad setting refused."""
from __future__ import annotations

import os
import subprocess
import sys

import pytest
from conftest import child_env, process_alive, scene_path

from pipeline.cli import main

pytestmark = pytest.mark.skipif(not hasattr(os, "sched_getaffinity"), reason="Linux only")

PROBE = "import clothjit, numba; print(clothjit.THREADS, numba.get_num_threads())"


def threads_of_a_child(**env: str) -> tuple[int, int]:
    base = {k: v for k, v in child_env().items()
            if k not in ("NUMBA_NUM_THREADS", "CLOTHPIPE_THREADS")}
    out = subprocess.run([sys.executable, "-c", PROBE], env=dict(base, **env),
                         capture_output=True, text=True, timeout=120, check=True).stdout
    chosen, running = map(int, out.split())
    return chosen, running


@pytest.fixture
def every_core_busy():
    """One CPU-bound process per core this process may run on, killed after the test."""
    procs = [subprocess.Popen([sys.executable, "-c", "while True: pass"])
             for _ in os.sched_getaffinity(0)]
    try:
        yield procs
    finally:
        for p in procs:
            p.kill()
            p.wait(timeout=10)
        assert not any(process_alive(p.pid) for p in procs)


def test_one_thread_when_every_core_is_busy(every_core_busy):
    assert threads_of_a_child() == (1, 1)


def test_settings_override_the_free_cores(every_core_busy):
    import numba

    most = numba.config.NUMBA_NUM_THREADS
    assert threads_of_a_child(CLOTHPIPE_THREADS="all") == (most, most)
    assert threads_of_a_child(CLOTHPIPE_THREADS="1") == (1, 1)
    assert threads_of_a_child(CLOTHPIPE_THREADS=str(most + 5)) == (most, most)  # capped
    assert threads_of_a_child(NUMBA_NUM_THREADS="1") == (1, 1)


@pytest.mark.parametrize("value", ["x", "0", "-2", "1.5", ""])
def test_a_bad_setting_is_refused_naming_the_variable(tmp_path, capsys, monkeypatch, value):
    monkeypatch.setenv("CLOTHPIPE_THREADS", value)
    out = tmp_path / "x.gif"
    assert main([str(scene_path("pinned2")), "--out", str(out), "--frames", "2"]) == 2
    err = capsys.readouterr().err
    assert err.startswith("render: CLOTHPIPE_THREADS: expected auto, all or a whole number >= 1")
    assert len(err.strip().splitlines()) == 1
    assert list(tmp_path.iterdir()) == []


def test_the_load_watch_sees_processes_that_start_after_it(every_core_busy):
    """The watch behind adjust_threads, on real busy processes: /proc/stat's busy time less
    this process's own leaves no core free."""
    import time

    import clothjit

    watch = clothjit._LoadWatch()
    time.sleep(clothjit.LOOK_EVERY * 2)
    assert watch.free_cores() == 1


def test_threads_follow_the_free_cores_only_where_they_were_chosen(monkeypatch):
    import numba

    import clothjit

    if numba.config.NUMBA_NUM_THREADS < 2:
        pytest.skip("needs 2 threads")
    monkeypatch.setattr(clothjit, "_AUTO", True)
    monkeypatch.setattr(clothjit, "_chosen", __import__("threading").local())
    monkeypatch.setattr(clothjit, "THREADS", 2)
    free = [1]
    monkeypatch.setattr(clothjit._watch, "free_cores", lambda: free[0])
    before = numba.get_num_threads()
    try:
        numba.set_num_threads(2)
        clothjit.adjust_threads()  # load came: down to the free core
        assert numba.get_num_threads() == 1
        free[0] = 2
        clothjit.adjust_threads()  # it went: back up
        assert numba.get_num_threads() == 2
        with clothjit.numba_threads(1):  # a caller's count is left alone
            free[0] = 2
            clothjit.adjust_threads()
            assert numba.get_num_threads() == 1
        monkeypatch.setattr(clothjit, "_AUTO", False)  # CLOTHPIPE_THREADS=all or a number
        free[0] = 1
        clothjit.adjust_threads()
        assert numba.get_num_threads() == 2
    finally:
        numba.set_num_threads(before)


@pytest.mark.parametrize("fidelity", ["exact", "auto"])
def test_a_simulation_looks_at_the_load_between_frames(monkeypatch, fidelity):
    from conftest import cloth_dict, scene_dict

    from pipeline import Simulation, simulation

    calls = []
    monkeypatch.setattr(simulation, "adjust_threads", lambda: calls.append(1))
    monkeypatch.setattr(simulation, "LOOK_EVERY", 0.0)  # a look due after every frame
    raw = scene_dict(cloth_dict(6, 6), steps_per_frame=4)
    raw["simulation"]["fidelity"] = fidelity
    sim = Simulation(raw)
    sim.advance(5)
    assert len(calls) == 5
    if fidelity == "exact":  # with no look due, the frames run in one kernel call after the first
        monkeypatch.setattr(simulation, "LOOK_EVERY", 1e9)
        calls.clear()
        sim.advance(5)
        assert len(calls) == 2

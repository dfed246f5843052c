"""Shared helpers of the simulator tests: tiny scene-dict builders and scene paths.

The dicts use only the course format plus `simulation` keys that the C++ reference
(shared/reference/cs184_ref) also understands, so the same dict can feed both.
"""
from __future__ import annotations

import os
from pathlib import Path

import numpy as np
import pytest


def pytest_configure(config):
    """Under pytest-xdist each worker runs numba's parallel kernels on one thread: two
    workers with two threads each on two cores stall every parfor barrier on a descheduled
    thread (seen: the suite at 14-20 min instead of 8). Results do not depend on it."""
    if os.environ.get("PYTEST_XDIST_WORKER"):
        import numba

        # before clothjit is imported: it sets the main thread's count from this variable
        # (else from the free cores, which two workers starting together both see free)
        os.environ["CLOTHPIPE_THREADS"] = "1"
        numba.set_num_threads(1)


#: Files whose tests start new processes (Dask workers, `render` under a signal, a fresh
#: interpreter) that load their kernels from numba's on-disk cache, and the shader report
#: (every shader's fragment stage, as in test_shading_golden). On a cold cache they run
#: last, when the other files have compiled and saved those kernels: run first, each new
#: process compiles them again, beside two test workers already busy on both cores.
#: Longest first (a cold run, 2026-11-27: 41, 33, 17.5, 12.5 and 0.5 s), so that the two
#: workers end close together: the longest last kept one worker alone for 20 s.
LAST = ("test_distributed.py", "test_signals.py", "test_jit_cache.py", "test_report.py",
        "test_disk_full.py")


def pytest_collection_modifyitems(config, items):
    """Files in pytest-xdist's order (most tests first, as its `--dist loadfile` would;
    pyproject turns its own reordering off), then LAST in that order."""
    count: dict[str, int] = {}
    for item in items:
        count[item.path.name] = count.get(item.path.name, 0) + 1

    def rank(item):
        name = item.path.name
        return (LAST.index(name), 0) if name in LAST else (-1, -count[name])

    items.sort(key=rank)  # stable: a file's tests keep their order


def process_alive(pid: int) -> bool:
    """Alive and not a zombie (from /proc)."""
    try:
        stat = Path(f"/proc/{pid}/stat").read_text()
    except OSError:
        return False
    return stat[stat.rindex(")") + 2:].split()[0] != "Z"


def child_env(**extra: str) -> dict:
    """os.environ for a child Python that imports the clothpipe these tests import (the
    installed package, or the tree when pytest found that), not a copy in its working
    folder: one source, hence one numba cache shared by the tests and their children.
    CI installs the package and runs pytest from the clone, where `python -c` would import
    the clone first and compile every kernel a second time, into the clone's cache."""
    import site

    import pipeline

    env = dict(os.environ)
    env["PYTHONSAFEPATH"] = "1"  # Python >= 3.11: no working folder first on sys.path
    home = str(Path(pipeline.__file__).resolve().parents[1])
    if home not in {str(Path(p).resolve()) for p in site.getsitepackages()}:
        env["PYTHONPATH"] = os.pathsep.join(
            [home] + [p for p in env.get("PYTHONPATH", "").split(os.pathsep) if p])
    env.update(extra)
    return env


ROOT = Path(__file__).resolve().parents[1]
SCENES = ROOT / "scenes"

#: The five scenes of the course (scene files kept unchanged in scenes/).
COURSE_SCENES = ("pinned2", "pinned4", "plane", "selfCollision", "sphere")


def scene_path(name: str) -> Path:
    return SCENES / f"{name}.json"


def cloth_dict(
    nw: int = 4,
    nh: int = 4,
    *,
    width: float = 1.0,
    height: float = 1.0,
    thickness: float = 0.01,
    orientation: int = 0,
    damping: float = 0.0,
    density: float = 1.0,
    ks: float = 100.0,
    structural: bool = True,
    shearing: bool = True,
    bending: bool = True,
    pinned=(),
) -> dict:
    """A `cloth` block with every key the course format requires."""
    return {
        "width": width,
        "height": height,
        "num_width_points": nw,
        "num_height_points": nh,
        "thickness": thickness,
        "orientation": orientation,
        "damping": damping,
        "density": density,
        "ks": ks,
        "enable_structural": structural,
        "enable_shearing": shearing,
        "enable_bending": bending,
        "pinned": [list(p) for p in pinned],
    }


def scene_dict(
    cloth: dict | None = None,
    *,
    gravity=(0.0, -9.8, 0.0),
    frames_per_sec: float = 90,
    steps_per_frame: int = 30,
    seed: int = 0,
    self_collision: bool = False,
    spheres=(),
    planes=(),
    planes_first: bool = False,
) -> dict:
    """A scene dict. `spheres` are (origin, radius, friction), `planes` (point, normal,
    friction); colliders act in the order of the keys, spheres first unless planes_first."""
    scene: dict = {"cloth": cloth if cloth is not None else cloth_dict()}
    sph = [{"origin": list(o), "radius": r, "friction": f} for o, r, f in spheres]
    pla = [{"point": list(p), "normal": list(n), "friction": f} for p, n, f in planes]
    order = (("plane", pla), ("sphere", sph)) if planes_first else (("sphere", sph), ("plane", pla))
    for key, items in order:
        if items:
            scene[key] = items
    scene["simulation"] = {
        "frames_per_sec": frames_per_sec,
        "steps_per_frame": steps_per_frame,
        "gravity": list(gravity),
        "seed": seed,
        "self_collision": self_collision,
    }
    return scene


def grid_index(i: int, j: int, nw: int) -> int:
    """Row-major index of point (row i, column j)."""
    return i * nw + j


def spring_pairs(nw: int, nh: int):
    """(p, q, kind) for every spring of SPEC section 2, written from the SPEC text (not from
    the model code): kind 0 structural, 1 shearing, 2 bending. Order is SPEC order."""
    out = []
    for i in range(nh):
        for j in range(nw):
            p = i * nw + j
            for di, dj, kind in ((0, -1, 0), (-1, 0, 0), (-1, -1, 1), (-1, 1, 1),
                                 (0, -2, 2), (-2, 0, 2)):
                i2, j2 = i + di, j + dj
                if 0 <= i2 < nh and 0 <= j2 < nw:
                    out.append((p, i2 * nw + j2, kind))
    return out


@pytest.fixture
def rng():
    return np.random.default_rng(12345)


@pytest.fixture(scope="module")
def serial_numba():
    """Run the kernels on one thread for the module (restored after). The results do not
    depend on the thread count (every parallel loop writes disjoint points); this only
    avoids the cost of thread barriers on tiny grids and on a loaded 2-core machine, where
    one thread is several times faster. Set CLOTH_TEST_THREADS to override."""
    import os

    from clothjit import numba_threads

    with numba_threads(int(os.environ.get("CLOTH_TEST_THREADS", "1"))):
        yield

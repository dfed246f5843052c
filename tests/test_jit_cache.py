"""shading.jit: numba's cache index stays right when processes save into it at once."""
from __future__ import annotations

import multiprocessing
import pickle

import pytest

SAVES = 150


def _save_many(folder: str, worker: int, start) -> None:
    import shading.jit  # noqa: F401  (installs the locked save)
    from numba.core.caching import IndexDataCacheFile

    cache = IndexDataCacheFile(folder, "f-1.py311", source_stamp=("stamp", 1))
    start.wait()
    for i in range(SAVES):
        key = (worker, i)
        cache.save(key, pickle.dumps(key))


def _saved(folder: str) -> dict:
    import shading.jit  # noqa: F401
    from numba.core.caching import IndexDataCacheFile

    cache = IndexDataCacheFile(folder, "f-1.py311", source_stamp=("stamp", 1))
    return {key: cache.load(key) for key in cache._load_index()}


def test_concurrent_saves_keep_every_entry_and_its_own_data(tmp_path):
    """Two processes save different keys of one function as fast as they can (numba's own
    save loses entries and points keys at each other's data here)."""
    ctx = multiprocessing.get_context("spawn")
    start = ctx.Event()
    procs = [ctx.Process(target=_save_many, args=(str(tmp_path), w, start)) for w in (0, 1)]
    for p in procs:
        p.start()
    start.set()
    for p in procs:
        p.join(60)
        assert p.exitcode == 0
    saved = _saved(str(tmp_path))
    assert len(saved) == 2 * SAVES
    wrong = [key for key, data in saved.items() if pickle.loads(data) != key]
    assert wrong == []


def test_import_shading_does_not_import_numba():
    import subprocess
    import sys

    code = "import sys, pipeline, shading; print('numba' in sys.modules)"
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.strip() == "False"

"""One numba compiler at a time per cache: an inter-process lock around numba's compiler.

Dask worker processes on one machine share a numba cache and mostly need the same kernels.
Two saves at once are safe (clothjit/__init__.py locks numba's cache index), but two workers
compiling the same kernels at once is twice the work on a first run. So while clothpipe
runs on a cluster every process (the client and each worker, through pipeline.cluster.client's
worker plugin) takes a file lock whenever numba takes its compiler lock: shared while it
loads kernels from the cache, exclusive from the moment it has to compile one until the
compiled kernel is saved, so the next process loads what the first compiled. Loading
stays parallel. The lock file lives in the numba cache folder (NUMBA_CACHE_DIR), else in
the temporary folder; the kernel releases it when a process dies, even by kill -9.

This listens to numba's documented event API: "numba:compiler_lock" (taken for every
load, compile and save) and "numba:compile" (a cache miss being compiled).
"""
from __future__ import annotations

import os
import tempfile
import threading

LOCK_NAME = "clothpipe-numba-compile.lock"

_installed = False
_guard = threading.Lock()


def lock_path() -> str:
    """The lock file shared by every process using this machine's numba cache."""
    import numba

    folder = numba.config.CACHE_DIR or tempfile.gettempdir()
    return os.path.join(folder, LOCK_NAME)


class _CacheLock:
    """Listener state: the lock's depth (numba's compiler lock is re-entrant and may be
    waited on by several threads) and the mode held (fcntl.LOCK_SH or LOCK_EX)."""

    def __init__(self, path: str):
        import fcntl

        self._fcntl = fcntl
        os.makedirs(os.path.dirname(path), exist_ok=True)
        self._fd = os.open(path, os.O_RDWR | os.O_CREAT, 0o666)
        self._mutex = threading.Lock()
        self._depth = 0
        self._mode = 0

    def _take(self, mode: int) -> None:
        if self._mode != mode:  # flock converts a held lock (not atomically: no deadlock)
            self._fcntl.flock(self._fd, mode)
            self._mode = mode

    def enter(self) -> None:
        with self._mutex:
            if self._depth == 0:
                self._take(self._fcntl.LOCK_SH)
            self._depth += 1

    def leave(self) -> None:
        with self._mutex:
            self._depth -= 1
            if self._depth == 0:
                self._fcntl.flock(self._fd, self._fcntl.LOCK_UN)
                self._mode = 0

    def compiling(self) -> None:
        with self._mutex:
            self._take(self._fcntl.LOCK_EX)


def install() -> None:
    """Take the cache lock around numba's compiler lock in this process (idempotent)."""
    global _installed
    with _guard:
        if _installed:
            return
        from numba.core import event

        lock = _CacheLock(lock_path())

        class CompilerLock(event.Listener):
            def on_start(self, ev):
                lock.enter()

            def on_end(self, ev):
                lock.leave()

        class Compile(event.Listener):
            def on_start(self, ev):
                lock.compiling()

            def on_end(self, ev):
                pass

        event.register("numba:compiler_lock", CompilerLock())
        event.register("numba:compile", Compile())
        _installed = True

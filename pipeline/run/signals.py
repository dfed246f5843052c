"""SIGINT, SIGTERM and SIGHUP as an exception, so that every output is cleaned up.

Inside `handled()`, the first of these signals raises `Terminated` in the main thread
(a KeyboardInterrupt, so every `except KeyboardInterrupt` / `except BaseException`
cleanup path runs: writers remove their temporary files, the MP4 encoder is killed, worker
processes are terminated). Further signals are then ignored until the block ends, so
the cleanup itself is never cut short. A signal that was ignored when the block began
(SIGHUP under nohup) stays ignored. The command exits with `exit_status(exc)`:
128 + the signal number (130 SIGINT, 143 SIGTERM, 129 SIGHUP), as shells report a process
a signal stopped.

A signal that lands while LLVM is calling back into Python (numba compiling or loading a
kernel: llvmlite's object cache is a ctypes callback) is held back: ctypes would print and
drop the exception, losing the signal or leaving LLVM with a half-set buffer (a crash). So
is one that lands while a kernel's entry point unboxes a first-class function argument (a
KernelPointer): numba's code calls `_numba_unpickle`, then `_get_wrapper_address` without
checking for an error in between, and the signal's exception became "TypeError:
_get_wrapper_address() missing 1 required positional argument" (an internal error, exit
1; once in 15 runs of the MP4 signal test). Python runs a handler at the first Python code
it meets, and after a kernel that is often numba's unboxing for the next call. A held-back
signal is sent again a moment later, until it finds the main thread back in plain Python.
So is one that lands inside `deferred()`, a step that must not be cut in half (starting
worker processes: a worker spawned but not yet sent its task would die reading an empty
pipe, with a traceback). And where Python itself drops the exception (the handler ran in
a weakref callback or a `__del__`: "Exception ignored in: <function
_get_module_lock.<locals>.cb>", the render then running to its end, seen once in the
suite), its unraisable hook hands the signal back, to be sent again.
"""
from __future__ import annotations

import signal
import sys
import threading
from collections.abc import Iterator
from contextlib import contextmanager

HANDLED = (signal.SIGINT, signal.SIGTERM, signal.SIGHUP)
_deferring = 0  # how many deferred() blocks the main thread is in
RESEND_SECONDS = 0.01  # how soon a held-back signal is sent again


class Terminated(KeyboardInterrupt):
    """A termination signal arrived; `signum` is its number."""

    def __init__(self, signum: int):
        super().__init__(signal.Signals(signum).name)
        self.signum = signum


def exit_status(exc: KeyboardInterrupt) -> int:
    """128 + the signal number; a plain KeyboardInterrupt counts as SIGINT (130)."""
    return 128 + getattr(exc, "signum", signal.SIGINT)


@contextmanager
def handled() -> Iterator[None]:
    """Within the block, SIGINT / SIGTERM / SIGHUP raise Terminated once (main thread only;
    elsewhere, or where signals cannot be set, the block runs unchanged)."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    fired = []
    active = threading.Lock()  # held while the handlers are ours
    main = threading.main_thread().ident

    def resend(signum: int) -> None:
        with active:
            if previous and not fired:
                signal.pthread_kill(main, signum)

    def handler(signum, frame):
        if fired:  # already stopping: let the cleanup finish
            return
        if _deferring or _inside_native_callback(frame):
            threading.Timer(RESEND_SECONDS, resend, (signum,)).start()
            return
        fired.append(signum)
        raise Terminated(signum)

    def dropped(info) -> None:
        """sys.unraisablehook: our Terminated dropped (a weakref callback, a __del__) is
        sent again, to be raised in code that passes it on."""
        if isinstance(info.exc_value, Terminated) and fired:
            signum = fired.pop()
            threading.Timer(RESEND_SECONDS, resend, (signum,)).start()
            return
        unraisable(info)

    # A signal ignored by whoever started us (nohup: SIGHUP) stays ignored.
    previous = {sig: signal.signal(sig, handler) for sig in HANDLED
                if signal.getsignal(sig) is not signal.SIG_IGN}
    unraisable, sys.unraisablehook = sys.unraisablehook, dropped
    try:
        yield
    finally:
        with active:
            for sig, old in previous.items():
                signal.signal(sig, old)
            previous.clear()
        sys.unraisablehook = unraisable


@contextmanager
def deferred() -> Iterator[None]:
    """Within the block, a signal that handled() turns into Terminated waits for the block
    to end (it is sent again until then)."""
    global _deferring
    _deferring += 1
    try:
        yield
    finally:
        _deferring -= 1


# Python modules that native code calls without passing an exception on: llvmlite's (ctypes
# callbacks from LLVM) and those numba's unboxing of a first-class function argument calls
CALLBACK_MODULES = ("llvmlite.", "numba.core.serialize", "numba.experimental.function_type")


def _inside_native_callback(frame) -> bool:
    """Whether `frame` or a caller of it is in CALLBACK_MODULES: native code may have called
    it, and would drop or mangle an exception."""
    while frame is not None:
        if frame.f_globals.get("__name__", "").startswith(CALLBACK_MODULES):
            return True
        frame = frame.f_back
    return False

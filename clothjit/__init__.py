"""The numba helpers that both the simulator (pipeline) and the renderer (shading) use, the
bottom layer: it imports numba and the standard library only.

numba's `njit` and `prange` for every kernel of clothpipe, with numba's on-disk cache
made safe for processes that compile at the same time and quicker to load from, numba's
inliner rid of a quadratic copy (`_InlinerCopies`), and its first compile in a process rid of
importing scipy.linalg (`_BlasCheckWhenUsed`); the numba threads of a process chosen from the
cores no other process keeps busy (`THREADS`).

numba's cache (`IndexDataCacheFile.save`) reads a function's index, picks a data-file name
not yet in it, writes the index, then the data. Two processes that compile different
signatures of one function at once both pick `<function>.1.nbc`, and one signature's index
entry ends up naming the other's machine code: a segfault when it is loaded (numba#4807,
numba#10128). Test workers (pytest-xdist), report pools, the compile helper of a first run
and Dask workers all compile into one cache. Here a save holds an exclusive lock on its cache
folder for the whole read-pick-write, and writes the data before the index, so that a reader
(which takes no lock) never finds an entry whose data is not in place. A kernel's cache
entry is stale when its file or any clothpipe file that file imports changes, not only its
own file as in numba (`cache_stamp`).
"""
from __future__ import annotations

import contextlib
import copy
import functools
import importlib.abc
import itertools
import os
import statistics
import sys
import threading
import time
from collections.abc import Iterator

import numba
from numba import prange
from numba.core import caching, event, ir, types
from numba.core.runtime import rtsys
from numba.core.types.function_type import WrapperAddressProtocol
from numba.core.typing.typeof import typeof_impl
from numba.experimental import function_type  # noqa: F401  (first-class functions: model, unboxing)

from . import cache_stamp

__all__ = ["STAGE", "THREADS", "KernelPointer", "adjust_threads", "argument_types", "njit",
           "numba_threads", "prange", "read_only", "threads_setting_error"]

LOCK_NAME = "clothpipe-cache.lock"

# numba caches a kernel compiled while a parallel kernel it calls came from the cache without
# the hook that starts numba's threads when the kernel is loaded (numba#8578, still in 0.68).
# Loaded first in a later process, such a kernel crashes it: a segfault, or "LLVM ERROR:
# Symbol not found: allocate_sched" (seen: scenes/flag.json with rk4 after swing with rk4
# and flag with Verlet). Every run starts those threads anyway; start them before any kernel.
numba.get_num_threads()


def busy_cores(samples: int = 5, interval: float = 0.001) -> int:
    """How many other threads are running or runnable on this machine now: the median of
    `samples` reads of the running count in /proc/loadavg (which counts the reader itself),
    `interval` s apart; 0 where there is no /proc/loadavg. Called before any parallel kernel
    has run, when this process has only the calling thread runnable."""
    counts = []
    try:
        for k in range(samples):
            if k:
                time.sleep(interval)
            with open("/proc/loadavg") as fh:
                counts.append(int(fh.read().split()[3].split("/")[0]) - 1)
    except (OSError, ValueError, IndexError):
        return 0
    return max(0, int(statistics.median(counts)))


def _cores() -> int:
    """The cores this process may run on (its affinity mask)."""
    try:
        return len(os.sched_getaffinity(0))
    except AttributeError:  # not Linux
        return os.cpu_count() or 1


THREADS_VARIABLE = "CLOTHPIPE_THREADS"


def _threads_setting() -> str:
    return os.environ.get(THREADS_VARIABLE, "auto").strip().lower()


def threads_setting_error() -> str | None:
    """What is wrong with CLOTHPIPE_THREADS, or None: `auto` (the default), `all` or a whole
    number >= 1."""
    value = _threads_setting()
    if value in ("auto", "all") or (value.isdigit() and int(value) >= 1):
        return None
    return (f"{THREADS_VARIABLE}: expected auto, all or a whole number >= 1, "
            f"got {os.environ[THREADS_VARIABLE]!r}")


def _threads_asked_for() -> int | None:
    """The thread count the environment sets, or None under auto: CLOTHPIPE_THREADS=all or an
    explicit NUMBA_NUM_THREADS keep numba's count (NUMBA_NUM_THREADS), a number sets it (at
    most that). A value that is none of these counts as auto (`render` refuses it first:
    threads_setting_error)."""
    limit = numba.config.NUMBA_NUM_THREADS
    value = _threads_setting()
    if value == "all" or "NUMBA_NUM_THREADS" in os.environ or limit <= 1:
        return limit
    if value.isdigit() and int(value) >= 1:
        return min(limit, int(value))
    return None


def threads_for_free_cores() -> int:
    """numba threads for this process's kernels: one per core of its affinity mask that no
    other process is keeping busy (busy_cores), at least 1, at most NUMBA_NUM_THREADS, unless
    the environment sets the count (_threads_asked_for).

    Every parallel loop ends on a barrier (several per simulation step), and when the machine
    has fewer free cores than threads, each barrier waits for a descheduled thread while the
    others spin: beside one CPU-bound process the README's command simulated 8-22x slower on
    2 threads than on 1 (benchmarks/load.py). One thread per free core avoids that; results
    do not depend on the thread count (every parallel loop writes disjoint points)."""
    asked = _threads_asked_for()
    if asked is not None:
        return asked
    return max(1, min(numba.config.NUMBA_NUM_THREADS, _cores() - busy_cores()))


#: whether the thread count follows the load (CLOTHPIPE_THREADS auto, the default)
_AUTO = _threads_asked_for() is None  # a few environment look-ups, once

#: The threads this process's parallel kernels run on unless told otherwise, chosen once at
#: import (before any parallel kernel): the main thread's count is set to it here; another
#: thread sets its own (numba_threads), numba's being per thread.
THREADS = threads_for_free_cores()
numba.set_num_threads(THREADS)

#: Seconds between looks at the machine's load while a simulation runs (adjust_threads).
LOOK_EVERY = 0.1


class _LoadWatch:
    """The cores no other process is using, from the last LOOK_EVERY seconds or more: the
    machine's busy time (/proc/stat: user, nice, system, irq, softirq, steal) minus this
    process's own (/proc/self/stat: utime, stime, its spinning threads included), in clock
    ticks, over the wall time between two looks."""

    def __init__(self) -> None:
        self.cores = _cores()
        self.tick = os.sysconf("SC_CLK_TCK") if hasattr(os, "sysconf") else 100
        self.last = self._look()
        self.free = THREADS

    @staticmethod
    def _look() -> tuple[float, int, int] | None:
        try:
            with open("/proc/stat") as fh:
                cpu = [int(v) for v in fh.readline().split()[1:9]]
            with open("/proc/self/stat") as fh:
                own = fh.read().rsplit(")", 1)[1].split()
        except (OSError, ValueError, IndexError):
            return None
        busy = cpu[0] + cpu[1] + cpu[2] + sum(cpu[5:8])  # idle and iowait left out
        return time.monotonic(), busy, int(own[11]) + int(own[12])

    def free_cores(self) -> int:
        if self.last is None or time.monotonic() - self.last[0] < LOOK_EVERY:
            return self.free
        now = self._look()
        if now is None:
            return self.free
        seconds = now[0] - self.last[0]
        others = ((now[1] - self.last[1]) - (now[2] - self.last[2])) / (seconds * self.tick)
        self.last = now
        self.free = max(1, self.cores - int(others + 0.5))
        return self.free


_watch = _LoadWatch()
_chosen = threading.local()  # the count adjust_threads last set in this thread


def adjust_threads() -> None:
    """Between frames: the calling thread's numba threads follow the cores other processes
    leave free (looked at every LOOK_EVERY s), so that load that starts during a run does not
    stall every parallel loop's barrier. Only under CLOTHPIPE_THREADS=auto, and only while the
    thread runs on the count chosen here (THREADS, or this function's last): a count a caller
    set (numba_threads) is left alone. Results do not depend on it."""
    if not _AUTO:
        return
    current = numba.get_num_threads()
    if current != getattr(_chosen, "threads", THREADS):
        return
    want = max(1, min(numba.config.NUMBA_NUM_THREADS, _watch.free_cores()))
    if want != current:
        numba.set_num_threads(want)
    _chosen.threads = want


# Options of the fragment stage (shading/shade.py) and of the helpers it calls rather than
# inlines: cached, releases the GIL, no zero-division checks (numpy error model), and
# floating-point contraction / reassociation / reciprocals (a few ulps; no assumptions
# about NaN or infinities). One set, so a helper's arithmetic is the same called or inlined.
STAGE = dict(cache=True, nogil=True, error_model="numpy",
             fastmath={"nsz", "arcp", "contract", "afn", "reassoc"})


def njit(*args, pointer: bool = False, **options):
    """numba.njit; `parallel=True` converts only explicit `prange` loops. Every parallel
    kernel here is a prange over chunks of scalar loops, so numba's other conversions
    (array expressions, reductions, fusion of loops) find nothing to do and only cost
    compile time (a first FEM element pass compiles about 1 s sooner without them).

    `pointer=True` for a kernel other kernels call through a KernelPointer: only those get
    numba's C wrapper (numba writes one for every kernel, so that any could be called through
    its address; a stepping kernel's flattens the System into C arguments: 632 of the 6272
    lines of IR of Verlet's on the sphere scene). Likewise a kernel only other kernels call
    takes `no_cpython_wrapper=True`: numba's Python entry unboxes every argument (the
    fragment stage's helpers, which take the whole Frame: fetch 0.79-0.84 s to compile
    without it, 0.97-1.24 s with it, 2026-11-27)."""
    options.setdefault("no_cfunc_wrapper", not pointer)
    if options.get("parallel") is True:
        options["parallel"] = dict(prange=True, comprehension=False, reduction=False,
                                   inplace_binop=False, setitem=False, numpy=False,
                                   stencil=False, fusion=False)
    return numba.njit(*args, **options)


def read_only(array):
    """A read-only view of `array`. numba types read-only and writable arrays apart, so a
    kernel's inputs passed always one way compile once, not twice."""
    view = array.view()
    view.flags.writeable = False
    return view


def argument_types(dispatcher, args: tuple) -> tuple:
    """numba's types of `args` as `dispatcher` would type them (a numba type stays itself)."""
    return tuple(a if isinstance(a, types.Type) else dispatcher.typeof_pyval(a) for a in args)


class KernelPointer(WrapperAddressProtocol):
    """A compiled kernel handed to other kernels as data: numba types it as a first-class
    function and its callers call it through its address.

    numba links the code of every kernel a kernel calls into the caller's module and
    optimises and generates that code again there (and a parallel loop does so four
    times); a kernel called through a pointer is compiled once, on its own, and its callers
    stay small. The kernel must be declared `njit(..., pointer=True)` (it needs numba's C
    wrapper) and must not raise (that wrapper cannot pass an exception on).
    Pickles as the dispatcher, the argument types and the return type (`returns`: none
    unless given); the address is the kernel's for those types in this process (compiled,
    or loaded from the cache, on first use).

    `present=False` gives a pointer of the same type that is never compiled and must never be
    called (its address is numba's -1, "no implementation"): a pass a scene does not use
    (wind, self-collision), whose caller tests a flag first. The caller's type is then the
    same with or without the pass, so it compiles once for both.
    """

    def __init__(self, dispatcher, args: tuple, returns: types.Type = types.none,
                 present: bool = True):
        if dispatcher.targetoptions.get("no_cfunc_wrapper"):
            raise TypeError(f"{dispatcher.py_func.__qualname__} has no C wrapper to be called "
                            "through a pointer: declare it njit(..., pointer=True)")
        self.dispatcher = dispatcher
        self.argtypes = argument_types(dispatcher, args)
        self.returns = returns
        self.present = present
        self._signature = returns(*self.argtypes)
        self.numba_type = types.FunctionType(self._signature)
        self._address = None if present else -1

    def signature(self):
        return self._signature

    def __wrapper_address__(self) -> int:
        if self._address is None:
            self.dispatcher.compile(self.argtypes)
            result = self.dispatcher.overloads[self.argtypes]
            self._address = result.library.get_pointer_to_function(
                result.fndesc.llvm_cfunc_wrapper_name)
        return self._address

    def __reduce__(self):
        return KernelPointer, (self.dispatcher, self.argtypes, self.returns, self.present)

    def __deepcopy__(self, memo) -> KernelPointer:
        return self  # immutable: a copied state or System shares it (and its address)


@typeof_impl.register(KernelPointer)
def _typeof_kernel_pointer(pointer: KernelPointer, c) -> types.FunctionType:
    """Its type, built once (numba's own typeof for the protocol builds it on every call)."""
    return pointer.numba_type


@contextlib.contextmanager
def _cache_lock(folder: str):
    """An exclusive lock on the cache folder (fcntl; no lock where fcntl is missing)."""
    try:
        import fcntl
    except ImportError:  # not POSIX: numba's own behaviour
        yield
        return
    fd = os.open(os.path.join(folder, LOCK_NAME), os.O_RDWR | os.O_CREAT, 0o666)
    try:
        fcntl.flock(fd, fcntl.LOCK_EX)
        yield
    finally:
        os.close(fd)  # closing releases the lock


def _locked_save(self, key, data) -> None:
    """IndexDataCacheFile.save under the folder's lock, data first, then the index."""
    with _cache_lock(self._cache_path):
        overloads = self._load_index()
        name = overloads.get(key)
        if name is None:
            taken = set(overloads.values())
            name = next(n for n in map(self._data_name, itertools.count(1)) if n not in taken)
        self._save_data(name, data)
        if overloads.get(key) != name:
            overloads[key] = name
            self._save_index(overloads)


caching.IndexDataCacheFile.save = _locked_save


def _load_overload(self, sig, target_context):
    """Cache.load_overload without refreshing the compiler's registries first.

    numba refreshes the target context before every load from the cache; its first refresh
    imports every implementation numba has (0.5-0.7 s on this machine, scipy.linalg among
    them for numba's BLAS check), which only compiling uses, and compiling refreshes on its
    own (compiler.compile_extra). Loading needs the runtime's symbols (NRT), which the
    refresh registered: they are registered here."""
    rtsys.initialize(target_context)
    with self._guard_against_spurious_io_errors():
        return self._load_overload(sig, target_context)


caching.Cache.load_overload = _load_overload

# numba stamps a cached kernel with its own file only: a kernel kept its old code after a
# helper it calls in another file changed. Stamped with its file's imports too: cache_stamp.
cache_stamp.install()


class _BlasCheckWhenUsed(importlib.abc.MetaPathFinder):
    """Skips the BLAS check numba.np.arraymath makes when it is imported (numba's first
    compile in a process imports it): that check imports scipy.linalg, 0.3 s on this machine
    (scipy's array-API layer imports numpy.f2py, which imports charset_normalizer), in every
    process that compiles. No kernel here calls BLAS, and scipy, a dependency, provides it;
    a kernel that does (np.dot) still runs numba's check, scipy.linalg and all, as it is
    typed. Finds no module: it only patches numba.np.linalg as arraymath is first imported.
    """

    def find_spec(self, name, path=None, target=None):
        if name == "numba.np.arraymath":
            sys.meta_path.remove(self)
            from numba.np import linalg

            check = getattr(linalg, "ensure_blas", None)
            if check is not None:
                linalg.ensure_blas = _checked_when_used(check)
        return None


def _checked_when_used(ensure_blas):
    """ensure_blas, except within arraymath's `_HAVE_BLAS = _check_blas()` (numba 0.68)."""

    @functools.wraps(ensure_blas)
    def checked_when_used():
        arraymath = sys.modules.get("numba.np.arraymath")
        if hasattr(arraymath, "_check_blas") and not hasattr(arraymath, "_HAVE_BLAS"):
            return  # BLAS is there: scipy is a dependency
        ensure_blas()

    return checked_when_used


if "numba.np.arraymath" not in sys.modules:
    sys.meta_path.insert(0, _BlasCheckWhenUsed())


class _InlinerCopies:
    """`copy` as numba's inliner sees it: a callee's blocks copied with one memo.

    numba's `inline="always"` (InlineWorker.inline_ir, numba 0.68) copies the callee's IR
    block by block, each with `copy.deepcopy` and a new memo, so each block copies the
    function's whole scope (every variable of the function) again: quadratic in the callee's
    size, and a nested inlined callee is copied again at each level (numba#8989,
    numba-cuda#688). Here the blocks copied during one inlining share one memo, as copying
    the blocks together would: the copy keeps the sharing of the original IR (one scope, a
    Var shared between blocks stays shared). The same machine code (the 166 kernels of four
    scenes and nine shaders compared, symbol names aside); the colliders' `_collide_range`
    compiles in 2.1-3.8 s instead of 2.9-5.7 s (six rounds alternately, one process), a
    cold README command takes about 10 % less CPU."""

    copy = staticmethod(copy.copy)

    def __init__(self) -> None:
        self.memo: dict | None = None  # the current inlining's, else None

    def deepcopy(self, x, memo=None):
        if memo is None and self.memo is not None and isinstance(x, ir.Block):
            memo = self.memo
        return copy.deepcopy(x, memo)


class _InlinerPatch(event.Listener):
    """Installs _InlinerCopies on numba's first compile in this process (a run that only
    loads kernels from the cache never imports the inliner, 15 ms), if numba's inliner
    still copies block by block."""

    done = False

    def on_start(self, ev) -> None:
        if self.done:
            return
        self.done = True
        from numba.core import inline_closurecall as inliner

        inline_ir = inliner.InlineWorker.inline_ir
        copy_ir = [c for c in inline_ir.__code__.co_consts
                   if getattr(c, "co_name", None) == "copy_ir"]
        if not (copy_ir and {"deepcopy", "blocks"} <= set(copy_ir[0].co_names)
                and inliner.copy is copy):
            return  # another numba: leave its inliner alone
        copies = _InlinerCopies()

        @functools.wraps(inline_ir)
        def one_memo_per_inlining(worker, *args, **kwargs):
            outer, copies.memo = copies.memo, {}
            try:
                return inline_ir(worker, *args, **kwargs)
            finally:
                copies.memo = outer

        inliner.copy = copies
        inliner.InlineWorker.inline_ir = one_memo_per_inlining

    def on_end(self, ev) -> None:
        pass


event.register("numba:compile", _InlinerPatch())


@contextlib.contextmanager
def numba_threads(n: int) -> Iterator[None]:
    """Run this thread's numba kernels on `n` threads (at most NUMBA_NUM_THREADS) inside
    the block; results do not depend on it (every parallel loop writes disjoint points)."""
    import numba

    before = numba.get_num_threads()
    numba.set_num_threads(max(1, min(n, numba.config.NUMBA_NUM_THREADS)))
    try:
        yield
    finally:
        numba.set_num_threads(before)

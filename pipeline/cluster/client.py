"""Dask distributed for `--workers N` and `--scheduler ADDR` (docs/distributed.md).

    with cluster.connect(args) as client:   # a LocalCluster of N processes, or a scheduler
        futures = [client.submit(task, plain_data, ...)]

Imported only when one of those flags is given, so a plain `render` never loads
`distributed`. Every task ships plain data (a scene file's bytes, positions and images as
numpy arrays); each worker process compiles or loads its numba kernels once and keeps
them. `WorkerSetup`, a worker plugin, takes the numba cache lock (clothjit.compile_lock)
in every worker, also in one the nanny restarts after a crash.
"""
from __future__ import annotations

import asyncio
import contextlib
import logging
import signal
import threading
from collections.abc import Iterator

import distributed
from distributed.diagnostics.plugin import WorkerPlugin

from clothjit import compile_lock
from pipeline.run.errors import UsageError

#: Seconds to wait for a scheduler: the handshake, then the client's connection.
CONNECT_TIMEOUT = 4.0


class ClusterError(UsageError):
    """The cluster cannot be reached or started (exit status 2)."""

    help_hint = False


class WorkerSetup(WorkerPlugin):
    """Runs in each worker process when it starts: takes the numba cache lock. `local`:
    the worker belongs to our LocalCluster, in the terminal's process group; it ignores
    SIGINT, which the client handles by closing the cluster (a Ctrl-C would otherwise
    also stop each worker with a traceback)."""

    idempotent = True
    name = "clothpipe-setup"

    def __init__(self, local: bool):
        self.local = local

    def setup(self, worker) -> None:
        compile_lock.install()
        if self.local and threading.current_thread() is threading.main_thread():
            signal.signal(signal.SIGINT, signal.SIG_IGN)


def _probe(address: str, timeout: float) -> None:
    """Connect and complete Dask's handshake within `timeout` s, or raise ClusterError.
    (distributed's own connect waits for the handshake without a time limit.)"""
    from distributed.comm import connect

    async def handshake():
        comm = await connect(address, timeout=timeout)
        await comm.close()

    try:
        asyncio.run(asyncio.wait_for(handshake(), timeout))
    except (OSError, asyncio.TimeoutError) as exc:
        why = "no answer" if isinstance(exc, asyncio.TimeoutError) else _reason(exc)
        raise ClusterError(f"--scheduler {address}: no Dask scheduler answered within "
                           f"{timeout:g} s ({why}); start one with 'dask scheduler' there, "
                           f"or use --workers N to run on this machine") from None


def _reason(exc: OSError) -> str:
    text = str(exc).strip()
    return text.splitlines()[-1] if text else type(exc).__name__


@contextlib.contextmanager
def connect(args) -> Iterator[distributed.Client]:
    """A client for args.scheduler, or for a new LocalCluster of args.workers processes
    (one thread each, on 127.0.0.1, closed on exit). On exit every future of the client is
    released (Dask cancels what has not run) and the client closed."""
    compile_lock.install()  # the client may render too (reports)
    local = None
    try:
        if args.scheduler is not None:
            _probe(args.scheduler, CONNECT_TIMEOUT)
            client = distributed.Client(args.scheduler, timeout=CONNECT_TIMEOUT,
                                        set_as_default=False)
        else:
            local = distributed.LocalCluster(
                n_workers=args.workers, threads_per_worker=1, processes=True,
                host="127.0.0.1", dashboard_address=None, silence_logs=logging.ERROR)
            client = distributed.Client(local, set_as_default=False)
    except OSError as exc:
        if local is not None:
            local.close()
        raise ClusterError(f"cannot start or reach the Dask cluster: {_reason(exc)}") from None
    try:
        client.register_plugin(WorkerSetup(local is not None))
        yield client
    finally:
        client.close()
        if local is not None:
            local.close()


def where(client: distributed.Client, args) -> str:
    """"2 Dask workers" or "8 Dask workers at tcp://HOST:PORT" (for summaries)."""
    n = len(client.scheduler_info(n_workers=-1)["workers"])
    at = f" at {args.scheduler}" if args.scheduler is not None else ""
    return f"{n} Dask worker{'s' * (n != 1)}{at}"


def worker_threads(client: distributed.Client) -> int:
    """Tasks the cluster runs at once (its worker threads), at least 1."""
    return max(1, sum(client.nthreads().values()))

"""Where sweep tasks run: local worker processes (default) or a Dask cluster.

A backend maps one picklable function over task payloads and yields ``(index, result)`` as tasks
finish, in completion order. The function never raises for a task's own failure (it returns the
error), so an exception out of a backend means the backend itself broke (a worker killed, a lost
scheduler); the sweep then stops and the tasks not yet stored are recomputed on the next run.

Threads: every task runs single-threaded (BLAS, OpenMP, numba, torch), so ``N`` workers use ``N``
cores and never oversubscribe them. Local workers inherit the limits through their environment;
Dask's nanny sets the same variables for its worker processes (``distributed.nanny``
pre-spawn environment) and the task function pins torch itself.
"""

from __future__ import annotations

import contextlib
import multiprocessing
import os
import threading
import time
from collections.abc import Callable, Iterator, Sequence

from clm_sim.errors import UserError

THREAD_VARIABLES = ("OMP_NUM_THREADS", "MKL_NUM_THREADS", "OPENBLAS_NUM_THREADS",
                    "NUMEXPR_NUM_THREADS", "VECLIB_MAXIMUM_THREADS", "NUMBA_NUM_THREADS")


@contextlib.contextmanager
def single_threaded_children():
    """Within the block, child processes start with one BLAS/OpenMP/numba thread each."""
    saved = {k: os.environ.get(k) for k in THREAD_VARIABLES}
    os.environ.update({k: "1" for k in THREAD_VARIABLES})
    try:
        yield
    finally:
        for k, v in saved.items():
            if v is None:
                os.environ.pop(k, None)
            else:
                os.environ[k] = v


def watch_parent(parent_pid: int) -> None:
    """Worker initializer: exit when the sweep process dies (even by SIGKILL), leaving no orphan
    computing a result nobody will store."""
    def watch():
        while True:
            if os.getppid() != parent_pid:
                os._exit(1)
            time.sleep(0.5)
    threading.Thread(target=watch, daemon=True, name="clm-sim-parent-watch").start()


def run_local(fn: Callable, payloads: Sequence, workers: int) -> Iterator[tuple[int, object]]:
    """Run ``fn(payload)`` in ``workers`` fresh processes (``spawn``: no state inherited from
    the parent, same behaviour on Linux, macOS and Windows)."""
    from concurrent.futures import FIRST_COMPLETED, ProcessPoolExecutor, wait

    if not payloads:
        return
    ctx = multiprocessing.get_context("spawn")
    with single_threaded_children():
        pool = ProcessPoolExecutor(max_workers=workers, mp_context=ctx,
                                   initializer=watch_parent, initargs=(os.getpid(),))
    try:
        with single_threaded_children():
            # Keep at most two tasks per worker queued: an interrupted sweep then has little
            # submitted-but-unstarted work to cancel, and memory stays bounded on huge grids.
            pending = {}
            todo = iter(enumerate(payloads))
            for _ in range(2 * workers):
                item = next(todo, None)
                if item is None:
                    break
                pending[pool.submit(fn, item[1])] = item[0]
        while pending:
            done, _ = wait(pending, return_when=FIRST_COMPLETED)
            for fut in done:
                index = pending.pop(fut)
                yield index, fut.result()
                item = next(todo, None)
                if item is not None:
                    with single_threaded_children():
                        pending[pool.submit(fn, item[1])] = item[0]
    except BaseException:
        # Interrupted or broken: stop the workers now instead of waiting for running tasks.
        for proc in list((pool._processes or {}).values()):
            proc.terminate()
        pool.shutdown(wait=False, cancel_futures=True)
        raise
    pool.shutdown(wait=True)


def run_dask(fn: Callable, payloads: Sequence, workers: int,
             scheduler: str | None = None) -> Iterator[tuple[int, object]]:
    """Run ``fn(payload)`` on a Dask cluster: the scheduler at ``scheduler`` (``tcp://host:8786``)
    or, without one, a ``LocalCluster`` of ``workers`` single-threaded worker processes."""
    try:
        from dask.distributed import Client, LocalCluster, as_completed
    except ImportError:
        raise UserError("--backend dask needs the optional extra: "
                        "pip install 'clm-sim[cluster]'") from None
    if not payloads:
        return
    with contextlib.ExitStack() as stack:
        if scheduler:
            client = stack.enter_context(Client(scheduler))
        else:
            cluster = stack.enter_context(LocalCluster(
                n_workers=workers, threads_per_worker=1, processes=True,
                dashboard_address=None, silence_logs=40))
            client = stack.enter_context(Client(cluster))
        # pure=False: a task is identified by our own key, never deduplicated by Dask's hashing.
        futures = {client.submit(fn, p, pure=False): i for i, p in enumerate(payloads)}
        try:
            for fut in as_completed(futures):
                yield futures[fut], fut.result()
        finally:
            client.cancel(list(futures))


BACKENDS = {"local": run_local, "dask": run_dask}

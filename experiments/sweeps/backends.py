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
from collections.abc import Callable, Iterator, Sequence

from clm_sim.errors import UserError
from experiments.processes.workers import run_local


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

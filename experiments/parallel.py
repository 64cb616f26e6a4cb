"""PGNN fits of independent seeds on worker processes, one thread each.

The fits of one table row differ only in their seed, so they run in a pool of ``spawn`` worker
processes (one per available core). Every fit pins torch and BLAS to one thread itself
(:func:`controllers.pgnn.model.one_thread`), so a fit gives the same bits in a worker and in the
calling process, and the pool changes the wall time, never a result. Inside a worker process of
another pool (a sweep task) the fits run in-process: pools do not nest.
"""

from __future__ import annotations

import atexit
import multiprocessing
import os
from concurrent.futures import ProcessPoolExecutor

from experiments.backends import single_threaded_children, watch_parent

_POOL: ProcessPoolExecutor | None = None


def cores() -> int:
    """CPU cores this process may use."""
    try:
        return len(os.sched_getaffinity(0))
    except AttributeError:  # not on Linux
        return os.cpu_count() or 1


def _pool() -> ProcessPoolExecutor:
    """The pool, started once per process (a spawned worker imports torch: seconds, paid once
    rather than per row); workers start single-threaded and exit with their parent, as the
    sweep's (:mod:`experiments.backends`)."""
    global _POOL
    if _POOL is None:
        _POOL = ProcessPoolExecutor(max_workers=cores(),
                                    mp_context=multiprocessing.get_context("spawn"),
                                    initializer=watch_parent, initargs=(os.getpid(),))
        atexit.register(_POOL.shutdown)
    return _POOL


def fit_pgnn(payload: tuple):
    """One PGNN fit: ``(settings, features, data, theta_lip, seed_sequence)`` -> fitted model."""
    import numpy as np

    from controllers.pgnn import PGNNFeedforward

    settings, features, data, theta_lip, seq = payload
    model = PGNNFeedforward(**settings, features=features)
    return model.fit_data(data=data, theta_lip=theta_lip, rng=np.random.default_rng(seq))


def map_fits(payloads: list) -> list:
    """``[fit_pgnn(p) for p in payloads]``, on the worker pool when there is more than one fit,
    more than one core and this is not already a pool's worker."""
    if len(payloads) < 2 or cores() < 2 or multiprocessing.parent_process() is not None:
        return [fit_pgnn(p) for p in payloads]
    with single_threaded_children():  # workers are spawned on submit and inherit this
        return list(_pool().map(fit_pgnn, payloads))

"""Work on worker processes: maps of tasks, and the pool of PGNN fits.

Two users: :func:`run_local` maps a function over task payloads in completion order (sweeps, the
studies; a study of several phases maps them on one :func:`local_pool`), and :func:`map_fits`
runs the PGNN fits of one table row on a pool kept for the process. How the workers start and
end (a fork server, one thread each, Ctrl-C left to the owner) is
:mod:`experiments.processes.worker_life`.

The fits of one table row differ only in their seed, so they run in a pool of worker processes
(one per available core). Every fit pins torch and BLAS to one thread itself
(:func:`clm_sim.numerics.single_threaded`), so a fit gives the same bits in a worker and in the
calling process, and the pool changes the wall time, never a result. Inside a worker process of
another pool (a sweep task) the fits run in-process: pools do not nest.
"""

from __future__ import annotations

import atexit
import contextlib
import multiprocessing
import os
from collections.abc import Callable, Iterator, Sequence
from concurrent.futures import FIRST_COMPLETED, ProcessPoolExecutor, as_completed, wait

from experiments.processes.worker_life import FIT_PRELOAD, new_pool, retire, spawning, stop


@contextlib.contextmanager
def local_pool(workers: int) -> Iterator[ProcessPoolExecutor]:
    """A pool of ``workers`` fresh processes (:func:`context`: no state inherited from the
    caller) for one or several :func:`run_local` maps in a row: a study of several phases starts
    its workers once, not once a phase. The block's end shuts it down; an exception (Ctrl-C, a failed task) kills its workers
    at once instead of waiting for running tasks."""
    with spawning():
        pool = new_pool(workers)
    try:
        yield pool
    except BaseException:
        stop(pool)
        raise
    finally:
        retire(pool)
    pool.shutdown(wait=True)


def run_local(fn: Callable, payloads: Sequence, workers: int,
              pool: ProcessPoolExecutor | None = None) -> Iterator[tuple[int, object]]:
    """Run ``fn(payload)`` in ``workers`` fresh processes (:func:`local_pool`), or on ``pool``
    (one of :func:`local_pool`, left running), yielding ``(index, result)`` as each finishes."""
    if not payloads:
        return
    if pool is None:
        with local_pool(workers) as pool:
            yield from run_local(fn, payloads, workers, pool)
        return
    with spawning():
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
                with spawning():
                    pending[pool.submit(fn, item[1])] = item[0]


def map_in_order(fn: Callable, payloads: Sequence, workers: int,
                 done: Callable[[int, int, object], None] | None = None,
                 pool: ProcessPoolExecutor | None = None) -> list:
    """``fn`` over ``payloads`` in this process (``workers`` <= 1) or in ``workers`` fresh ones
    (:func:`run_local`, on ``pool`` where one is given), the results in payload order, so they
    never depend on ``workers``; ``done(count, index, result)`` as each one finishes (for
    progress lines)."""
    results: list = [None] * len(payloads)
    it = ((i, fn(p)) for i, p in enumerate(payloads)) if workers <= 1 else \
        run_local(fn, payloads, min(workers, len(payloads)), pool)
    for count, (index, result) in enumerate(it, 1):
        results[index] = result
        if done is not None:
            done(count, index, result)
    return results


_POOL: ProcessPoolExecutor | None = None


def cores() -> int:
    """CPU cores this process may use."""
    try:
        return len(os.sched_getaffinity(0))
    except AttributeError:  # not on Linux
        return os.cpu_count() or 1


def _pool() -> ProcessPoolExecutor:
    """The pool, started once per process (its workers' first fit loads torch's kernels: paid
    once rather than per row); workers start single-threaded and exit with their owner, as the
    sweeps' (:func:`run_local`)."""
    global _POOL
    if _POOL is None:
        _POOL = new_pool(cores())
        atexit.register(stop_fits)
    return _POOL


def stop_fits() -> None:
    """End the PGNN fit pool, if one was started (at exit, and on an interruption)."""
    global _POOL
    pool, _POOL = _POOL, None
    if pool is not None:
        retire(pool)
        stop(pool)


def fit_pgnn(payload: tuple):
    """One PGNN fit: ``(settings, features, data, theta_lip, seed_sequence)`` -> fitted model
    (``settings``: the keyword arguments of :class:`controllers.pgnn.PGNNFeedforward`)."""
    return fit_pgnn_reusing((*payload, None))[0]


def fit_pgnn_reusing(payload: tuple):
    """One PGNN fit that reuses and adds to a start cache: ``(settings, features, data,
    theta_lip, seed_sequence, starts)`` -> ``(fitted model, added)`` (``starts``: a
    :class:`controllers.pgnn.starts.StartCache`, see
    :meth:`controllers.pgnn.PGNNFeedforward.fit_data`; ``added``: the outcomes the fit added to
    it, for the caller to merge, because a pool's worker fills its own copy: only they travel
    back)."""
    import numpy as np

    from controllers.pgnn import PGNNFeedforward

    settings, features, data, theta_lip, seq, starts = payload
    held = set() if starts is None else set(starts.keys())
    model = PGNNFeedforward(**settings, features=features)
    model.fit_data(data=data, theta_lip=theta_lip, rng=np.random.default_rng(seq), reuse=starts)
    return model, None if starts is None else starts.since(held)


def fit_pinned(payload: tuple):
    """One PGNN fit with pinned physical parameters: ``(settings, features, data, theta_lip,
    beta0, pinned)`` -> fitted model (a point of the cost's profile)."""
    from controllers.pgnn import PGNNFeedforward

    settings, features, data, theta_lip, beta0, pinned = payload
    model = PGNNFeedforward(**settings, features=features)
    return model.fit_pinned(data=data, theta_lip=theta_lip, beta0=beta0, pinned=pinned)


def map_fits(payloads: list, fn: Callable = fit_pgnn,
             on_done: Callable | None = None) -> list:
    """``[fn(p) for p in payloads]`` (default :func:`fit_pgnn`; or :func:`fit_pinned`), on the
    worker pool when there is more than one fit, more than one core and this is not already a
    pool's worker; ``on_done(result)`` is called as each one finishes (in completion order).
    The payloads need no torch (:mod:`controllers.pgnn.data`): a caller that has not imported it
    starts the workers first, and loads it when the first fitted model is unpickled (in the
    pool's result thread)."""
    if len(payloads) < 2 or cores() < 2 or multiprocessing.parent_process() is not None:
        results = []
        for p in payloads:
            results.append(fn(p))
            if on_done is not None:
                on_done(results[-1])
        return results
    try:
        with spawning(FIT_PRELOAD):  # workers are spawned on submit and inherit this
            futures = [_pool().submit(fn, p) for p in payloads]
        if on_done is not None:
            for fut in as_completed(futures):
                on_done(fut.result())
        return [f.result() for f in futures]
    except BaseException:  # interrupted (or a worker died): no waiting for the running fits
        stop_fits()
        raise

"""Worker processes: the one place where clm-sim starts them.

Every worker starts single-threaded (BLAS, OpenMP, numba, torch: :func:`single_threaded_children`)
and exits with the process that started it even when that process is killed
(:func:`watch_parent`). Workers come from a fork server (:func:`context`): a clean process,
started once per clm-sim process with the libraries the workers use already imported (torch,
python-control, scipy, numba: 4 to 6 s of CPU that each fresh ``spawn`` process paid again),
which forks each worker. Where the platform has no fork server, workers are ``spawn``
processes. Two users: :func:`run_local` maps a function over task payloads in
completion order (sweeps, the studies; a study of several phases maps them on one
:func:`local_pool`), and :func:`map_fits` runs the PGNN fits of one table row on a pool kept
for the process.

PGNN fits of independent seeds on worker processes, one thread each.

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
import signal
import sys
import threading
import time
from collections.abc import Callable, Iterator, Sequence
from concurrent.futures import FIRST_COMPLETED, ProcessPoolExecutor, as_completed, wait


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


_STOP_SIGNALS = {signal.SIGINT, signal.SIGTERM}
# Held while workers are being started (their signals set to "ignore"): a signal that comes
# meanwhile is handed to the main thread once it is released (experiments.cli).
SPAWNING = threading.Lock()


@contextlib.contextmanager
def _spawning():
    """Around every call that may start a worker: child processes start with one thread each
    and with Ctrl-C and SIGTERM ignored (a disposition a new process inherits), so a signal to
    the process group while a worker starts cannot print a traceback in it (the owner alone
    answers, and ends its workers). With a fork server (:func:`context`) that holds for the
    server's start only: every worker is a copy of it, with its dispositions and environment,
    and the block itself runs with this process's signals as they are (a Ctrl-C while the
    server still imports its libraries interrupts the wait for the first worker at once)."""
    global _SERVER_FAILED
    if context().get_start_method() == "forkserver":
        from multiprocessing import forkserver

        try:
            with _starting():
                forkserver.ensure_running()
        except OSError:  # no socket in the temporary folder (read-only, full): spawn workers
            _SERVER_FAILED = True
    if context().get_start_method() == "forkserver":
        yield
    else:
        with _starting():
            yield


@contextlib.contextmanager
def _starting():
    """Child processes started within the block start single-threaded, with Ctrl-C and SIGTERM
    ignored. A command line process receives its signals in a thread of its own
    (:func:`experiments.process.receive_signals`), which waits for :data:`SPAWNING` before it
    passes one on, so none is lost."""
    main = threading.current_thread() is threading.main_thread()
    mask = main and hasattr(signal, "pthread_sigmask")
    with SPAWNING:
        if mask:
            previous_mask = signal.pthread_sigmask(signal.SIG_BLOCK, set())
            # multiprocessing's resource tracker unblocks both signals in this thread once it
            # has started it: start it before they are ignored, then block them again.
            _start_resource_tracker()
            signal.pthread_sigmask(signal.SIG_BLOCK, _STOP_SIGNALS)
        handlers = ({sig: signal.signal(sig, signal.SIG_IGN) for sig in _STOP_SIGNALS}
                    if main else {})
        try:
            with single_threaded_children():
                yield
        finally:
            for sig, handler in handlers.items():
                signal.signal(sig, handler)
            if mask:
                signal.pthread_sigmask(signal.SIG_SETMASK, previous_mask)


def _start_resource_tracker() -> None:
    """Start multiprocessing's resource tracker with its stderr on the null device: after an
    interrupted command it removes the pools' semaphores and would say so, in lines of its own
    beside the command's one line."""
    from multiprocessing import resource_tracker

    tracker = resource_tracker._resource_tracker
    if getattr(tracker, "_fd", None) is not None:
        return
    with contextlib.suppress(Exception):
        saved = os.dup(2)
        try:
            null = os.open(os.devnull, os.O_WRONLY)
            os.dup2(null, 2)
            os.close(null)
            resource_tracker.ensure_running()
        finally:
            os.dup2(saved, 2)
            os.close(saved)


# What the fork server imports before it forks the first worker: every library a worker's task
# uses (a fit: torch; a replay or a sweep task: python-control for the PID design, numba; the
# compiled kernels themselves load from numba's cache at a worker's first call). Paid once per
# clm-sim process, not once per worker.
PRELOAD = ("numpy", "scipy.linalg", "scipy.optimize", "scipy.signal", "control", "torch",
           "clm_sim.loop", "controllers.pgnn", "controllers.pgnn.model", "experiments.workers",
           "experiments.runner", "experiments.testbed")


def context() -> multiprocessing.context.BaseContext:
    """The start method of every worker: ``forkserver`` with :data:`PRELOAD` on Linux, else
    ``spawn`` (macOS has a fork server too, but its system libraries are not safe to use in a
    forked copy of a process that loaded them; Windows has none), and ``spawn`` too once the
    server could not start here (its socket needs a writable temporary folder). A forked worker is a copy of
    the fork server, a process started for this purpose that never computes, so it inherits
    imported modules and nothing of the caller's state; the server itself starts inside
    :func:`_spawning` (one thread per library, Ctrl-C and SIGTERM ignored) and hands that to
    every worker."""
    if not sys.platform.startswith("linux") or _SERVER_FAILED:
        return multiprocessing.get_context("spawn")
    ctx = multiprocessing.get_context("forkserver")
    ctx.set_forkserver_preload(["__main__", *PRELOAD])
    global _STOP_AT_EXIT
    if not _STOP_AT_EXIT:
        _STOP_AT_EXIT = True
        atexit.register(stop_server)
    return ctx


_STOP_AT_EXIT = False
_SERVER_FAILED = False  # the fork server could not start in this process: spawn from then on


def stop_server() -> None:
    """End this process's fork server, if it started one, and wait until it has gone (a
    command ends with no process of its own left behind), every pool's workers first; a later
    pool starts a new one. Reads private attributes of :mod:`multiprocessing.forkserver` (those
    of CPython 3.11); where a Python has others, this does nothing and the server exits by
    itself once this process and its workers have ended."""
    from multiprocessing import forkserver

    server = forkserver._forkserver
    lock = getattr(server, "_lock", None)
    if getattr(server, "_forkserver_pid", None) is None or lock is None \
            or not lock.acquire(timeout=1.0):
        return
    try:
        pid, alive = server._forkserver_pid, server._forkserver_alive_fd
        address = server._forkserver_address
        server._forkserver_pid = server._forkserver_alive_fd = server._forkserver_address = None
        kill_all()
        # Killed, not asked: it computes nothing and may still be importing its libraries
        # (seconds before it reads its pipe); its workers are killed above.
        with contextlib.suppress(OSError):
            os.kill(pid, signal.SIGKILL)
        with contextlib.suppress(ChildProcessError):
            os.waitpid(pid, 0)
        with contextlib.suppress(OSError, TypeError):
            os.close(alive)
        with contextlib.suppress(OSError, TypeError):
            if not address.startswith("\0"):  # a file, not Linux's abstract namespace
                os.unlink(address)
    except AttributeError:  # another Python's forkserver: it exits after this process
        pass
    finally:
        lock.release()


def remove_temp_dir() -> None:
    """Remove multiprocessing's temporary folder of this process now, for a process about to
    end with ``os._exit`` (no exit clean-up runs): it held the fork server's socket, and the
    sockets through which workers and this process handed each other torch's tensors. Their own
    clean-ups run first (they unlink those sockets, and would fail on a folder already gone),
    then the folder's. Every other ending leaves this to multiprocessing's exit function, which
    runs them in the same order."""
    from multiprocessing import util

    with contextlib.suppress(Exception):
        pending = list(util._finalizer_registry.values())
        for finalizer in pending:
            if getattr(finalizer, "_callback", None) is os.unlink:
                finalizer()
        for finalizer in pending:
            if getattr(finalizer, "_callback", None) is util._remove_temp_dir:
                finalizer()


def stop(pool: ProcessPoolExecutor) -> None:
    """End ``pool`` now: its workers killed (they write no file and ignore SIGTERM), queued
    work cancelled, without waiting for running tasks."""
    procs = list((getattr(pool, "_processes", None) or {}).values())
    for proc in procs:
        with contextlib.suppress(Exception):
            proc.kill()
    with contextlib.suppress(Exception):
        pool.shutdown(wait=False, cancel_futures=True)
    deadline = time.monotonic() + 1.0
    for proc in procs:
        with contextlib.suppress(Exception):
            proc.join(max(0.0, deadline - time.monotonic()))


_POOLS: set = set()  # the pools of this process that are running now


def kill_all() -> None:
    """Kill every worker of this process's pools at once, without waiting (for a process about
    to end at once)."""
    for pool in list(_POOLS):
        for proc in list((getattr(pool, "_processes", None) or {}).values()):
            with contextlib.suppress(Exception):
                proc.kill()


def _alive(pid: int) -> bool:
    """Whether process ``pid`` runs (a zombie, killed and not yet reaped, does not)."""
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        return True
    try:
        with open(f"/proc/{pid}/stat", "rb") as f:
            return f.read().rsplit(b")", 1)[1].split()[0] != b"Z"
    except (OSError, IndexError):
        return True  # no /proc: kill(pid, 0) is all there is


def watch_parent(owner_pid: int) -> None:
    """Worker initializer: ignore Ctrl-C and SIGTERM (the owner, the process whose pool this
    is, handles them and ends the workers) and exit when the owner dies (even by SIGKILL) or
    the process that started this worker does (the fork server, or the owner itself for a
    ``spawn`` worker), leaving no orphan computing a result nobody will store."""
    for sig in _STOP_SIGNALS:  # already ignored since the start (see _spawning), for good
        signal.signal(sig, signal.SIG_IGN)
    starter = os.getppid()

    def watch():
        while True:
            if os.getppid() != starter or not _alive(owner_pid):
                os._exit(1)
            time.sleep(0.5)
    threading.Thread(target=watch, daemon=True, name="clm-sim-parent-watch").start()


@contextlib.contextmanager
def local_pool(workers: int) -> Iterator[ProcessPoolExecutor]:
    """A pool of ``workers`` fresh processes (:func:`context`: no state inherited from the
    caller) for one or several :func:`run_local` maps in a row: a study of several phases starts
    its workers once, not once a phase. The block's end shuts it down; an exception (Ctrl-C, a failed task) kills its workers
    at once instead of waiting for running tasks."""
    with _spawning():
        pool = ProcessPoolExecutor(max_workers=workers, mp_context=context(),
                                   initializer=watch_parent, initargs=(os.getpid(),))
    _POOLS.add(pool)
    try:
        yield pool
    except BaseException:
        stop(pool)
        raise
    finally:
        _POOLS.discard(pool)
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
    with _spawning():
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
                with _spawning():
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
        _POOL = ProcessPoolExecutor(max_workers=cores(),
                                    mp_context=context(),
                                    initializer=watch_parent, initargs=(os.getpid(),))
        _POOLS.add(_POOL)
        atexit.register(stop_fits)
    return _POOL


def stop_fits() -> None:
    """End the PGNN fit pool, if one was started (at exit, and on an interruption)."""
    global _POOL
    pool, _POOL = _POOL, None
    if pool is not None:
        _POOLS.discard(pool)
        stop(pool)


def fit_pgnn(payload: tuple):
    """One PGNN fit: ``(settings, features, data, theta_lip, seed_sequence)`` -> fitted model
    (``settings``: the keyword arguments of :class:`controllers.pgnn.PGNNFeedforward`)."""
    return fit_pgnn_reusing((*payload, None))[0]


def fit_pgnn_reusing(payload: tuple):
    """One PGNN fit that reuses and adds to a start cache: ``(settings, features, data,
    theta_lip, seed_sequence, starts)`` -> ``(fitted model, starts)`` (``starts``: a
    :class:`controllers.pgnn.starts.StartCache`, see
    :meth:`controllers.pgnn.PGNNFeedforward.fit_data`; returned because a pool's worker fills
    its own copy)."""
    import numpy as np

    from controllers.pgnn import PGNNFeedforward

    settings, features, data, theta_lip, seq, starts = payload
    model = PGNNFeedforward(**settings, features=features)
    model.fit_data(data=data, theta_lip=theta_lip, rng=np.random.default_rng(seq), reuse=starts)
    return model, starts


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
        with _spawning():  # workers are spawned on submit and inherit this
            futures = [_pool().submit(fn, p) for p in payloads]
        if on_done is not None:
            for fut in as_completed(futures):
                on_done(fut.result())
        return [f.result() for f in futures]
    except BaseException:  # interrupted (or a worker died): no waiting for the running fits
        stop_fits()
        raise

"""The life of a worker process: how clm-sim starts one, and how it ends.

Every worker starts single-threaded (BLAS, OpenMP, numba, torch: :func:`single_threaded_children`)
and with Ctrl-C and SIGTERM blocked or ignored (:func:`spawning`: the owner alone answers
them; :func:`watch_parent` ignores them for good), and exits
with the process that owns it even when that process is killed (:func:`watch_parent`). Workers
come from a fork server (:func:`context`): a clean process, started once per clm-sim process with
the libraries the workers use already imported (torch, python-control, scipy, numba: 4 to 6 s of
CPU that each fresh ``spawn`` process paid again), which forks each worker. Where the platform
has no fork server, workers are ``spawn`` processes. Every pool is made by :func:`new_pool` and
known here until :func:`retire`, so that a process ending at once can kill every worker it owns
and its fork server (:func:`kill_now`; an orderly end: :func:`stop`, :func:`stop_server`). What
runs on the pools is
:mod:`experiments.processes.workers`.
"""

from __future__ import annotations

import atexit
import contextlib
import gc
import multiprocessing
import os
import signal
import sys
import threading
import time
from concurrent.futures import ProcessPoolExecutor

from clm_sim.numerics import THREAD_VARIABLES


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


# The signals that stop a command (experiments.processes.process.CODES): Ctrl-C, SIGTERM, and where
# the platform has them SIGHUP (a closed terminal, a dropped ssh connection) and SIGQUIT (Ctrl-\\).
_STOP_SIGNALS = {signal.SIGINT, signal.SIGTERM,
                 *(getattr(signal, name) for name in ("SIGHUP", "SIGQUIT")
                   if hasattr(signal, name))}
# Held while workers are being started (their signals set to "ignore"): a signal that comes
# meanwhile is handed to the main thread once it is released (experiments.processes.process).
SPAWNING = threading.Lock()


@contextlib.contextmanager
def spawning(libraries: tuple[str, ...] | None = None):
    """Around every call that may start a worker: child processes start with one thread each
    and with Ctrl-C and SIGTERM blocked or ignored (a mask and a disposition a new process
    inherits: :func:`_starting`), so a signal to
    the process group while a worker starts cannot print a traceback in it (the owner alone
    answers, and ends its workers). With a fork server (:func:`context`) that holds for the
    server's start only: every worker is a copy of it, with its dispositions and environment,
    and the block itself runs with this process's signals as they are (a Ctrl-C while the
    server still imports its libraries interrupts the wait for the first worker at once).
    ``libraries``: what a server started here imports (default :data:`PRELOAD`; the fit pool's
    :data:`FIT_PRELOAD`); a server already running keeps its own, and a worker imports what it
    lacks."""
    global _SERVER_FAILED
    if context().get_start_method() == "forkserver":
        from multiprocessing import forkserver

        try:
            with _starting():
                context().set_forkserver_preload(["__main__", *(libraries or PRELOAD)])
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
    blocked (a new process inherits the signal mask, through ``exec`` too) and, where they were
    not blocked here already, ignored. A command line process has them blocked and receives
    them in a thread of its own (:func:`experiments.processes.process.receive_signals`), which waits
    for :data:`SPAWNING` before it passes one on, so none is lost; their handlers are then left as
    they are: setting "ignore" discards a signal that is pending, one the signal thread has not
    yet taken (a sweep's SIGTERM was lost so, when it came as the next task was submitted)."""
    main = threading.current_thread() is threading.main_thread()
    mask = main and hasattr(signal, "pthread_sigmask")
    with SPAWNING:
        blocked = set()
        if mask:
            previous_mask = signal.pthread_sigmask(signal.SIG_BLOCK, set())
            blocked = _STOP_SIGNALS & set(previous_mask)
            # multiprocessing's resource tracker unblocks both signals in this thread once it
            # has started it: start it before they are ignored, then block them again.
            _start_resource_tracker()
            signal.pthread_sigmask(signal.SIG_BLOCK, _STOP_SIGNALS)
        handlers = ({sig: signal.signal(sig, signal.SIG_IGN) for sig in _STOP_SIGNALS - blocked}
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
           "clm_sim.loop", "controllers.pgnn", "controllers.pgnn.model",
           "experiments.processes.worker_life", "experiments.processes.workers",
           "experiments.runner", "experiments.testbed")
# A pool of PGNN fits (experiments.processes.workers.map_fits) needs only torch and the fit's
# modules: the server then imports in 3 s of CPU what PRELOAD takes 5 s for, and the first fit
# waits for it.
FIT_PRELOAD = ("numpy", "scipy.linalg", "threadpoolctl", "torch", "controllers.pgnn",
               "controllers.pgnn.model", "experiments.processes.worker_life",
               "experiments.processes.workers")


def context() -> multiprocessing.context.BaseContext:
    """The start method of every worker: ``forkserver`` on Linux (the libraries it imports:
    :func:`spawning`), else ``spawn`` (macOS has a fork server too, but its system libraries are
    not safe to use in a forked copy of a process that loaded them; Windows has none), and
    ``spawn`` too once the server could not start here (its socket needs a writable temporary
    folder). A forked worker is a copy of
    the fork server, a process started for this purpose that never computes, so it inherits
    imported modules and nothing of the caller's state; the server itself starts inside
    :func:`spawning` (one thread per library, Ctrl-C and SIGTERM ignored) and hands that to
    every worker."""
    if not sys.platform.startswith("linux") or _SERVER_FAILED:
        return multiprocessing.get_context("spawn")
    ctx = multiprocessing.get_context("forkserver")
    global _STOP_AT_EXIT
    if not _STOP_AT_EXIT:
        _STOP_AT_EXIT = True
        atexit.register(stop_server)
    return ctx


_STOP_AT_EXIT = False
_SERVER_FAILED = False  # the fork server could not start in this process: spawn from then on


def stop_server() -> None:
    """End this process's fork server, if it started one, and wait until it has gone (a
    command ends with no process of its own left behind), every process it forked first (the
    pools' workers, and one being forked that no pool knows yet); a later pool starts a new
    one. Reads private attributes of :mod:`multiprocessing.forkserver` (those
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
        _STOPPING.add(pid)  # for kill_now, from another thread, until it is killed
        server._forkserver_pid = server._forkserver_alive_fd = server._forkserver_address = None
        # Killed, not asked: it computes nothing and may still be importing its libraries
        # (seconds before it reads its pipe). With every process it forked: the pools' workers
        # and one it may be forking now, which no pool knows yet and which, once this process
        # has removed the pools' semaphores, would fail to read its task with a traceback
        # (:func:`_kill_server`).
        _kill_server(pid)
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


_STOPPING: set[int] = set()  # fork servers that stop_server is ending now


def _kill_server(pid: int) -> None:
    """Kill fork server ``pid`` and every process it forked: stopped first (SIGSTOP), so that
    it forks no other while its children are listed, then killed at once, whatever interrupts
    this (a stopped server never exits by itself), then the children it had."""
    try:
        with contextlib.suppress(OSError):
            os.kill(pid, signal.SIGSTOP)
        _wait_stopped(pid)
        children = _children(pid)
    finally:
        with contextlib.suppress(OSError):
            os.kill(pid, signal.SIGKILL)
        _STOPPING.discard(pid)
    for child in children:
        with contextlib.suppress(OSError):
            os.kill(child, signal.SIGKILL)


def kill_now() -> None:
    """For a process about to end at once (``os._exit``), whatever its other threads are
    doing: every worker of its pools killed, and its fork server (one that :func:`stop_server`
    is ending now included) with every process it forked; no lock taken, nothing waited for
    but the server's stop (:func:`_wait_stopped`)."""
    from multiprocessing import forkserver

    kill_all()
    pids = set(_STOPPING)
    with contextlib.suppress(Exception):
        pids.add(forkserver._forkserver._forkserver_pid)
    for pid in pids - {None}:
        with contextlib.suppress(Exception):
            _kill_server(pid)


def _stat(pid: int) -> list[bytes]:
    """The fields of ``/proc/PID/stat`` after the command name (state, parent, ...); empty
    where there is no such process or no ``/proc``."""
    try:
        with open(f"/proc/{pid}/stat", "rb") as f:
            return f.read().rsplit(b")", 1)[1].split()
    except (OSError, IndexError):
        return []


def _wait_stopped(pid: int, timeout_s: float = 0.5) -> None:
    """Wait until process ``pid``, sent SIGSTOP, has stopped (a stop is delivered
    asynchronously: a fork under way completes first), at most ``timeout_s``."""
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        fields = _stat(pid)
        if not fields or fields[0] in (b"T", b"t", b"Z"):
            return
        time.sleep(0.001)


def _children(pid: int) -> list[int]:
    """The processes whose parent is ``pid``, from ``/proc`` (none where it is missing)."""
    try:
        names = [n for n in os.listdir("/proc") if n.isdigit()]
    except OSError:
        return []
    parent = str(pid).encode()
    return [int(n) for n in names if _stat(int(n))[1:2] == [parent]]


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
    work cancelled, without waiting for running tasks. The killed workers are waited for (at
    most a second in all): the fork server then reaps them, and their CPU time counts in this
    process's children's, as ``/usr/bin/time`` reports it. The fork server is then stopped,
    with every process it forked (:func:`stop_server`; a later pool starts a new one), before
    the pool's shutdown: an interruption may come while the server forks a worker that no pool
    knows yet, and that worker, left alive, would read its task after the shutdown has removed
    the pool's semaphores, and print a traceback."""
    procs = list((getattr(pool, "_processes", None) or {}).values())
    for proc in procs:
        with contextlib.suppress(Exception):
            proc.kill()
    deadline = time.monotonic() + 1.0
    for proc in procs:
        with contextlib.suppress(Exception):
            proc.join(max(0.0, deadline - time.monotonic()))
    stop_server()
    with contextlib.suppress(Exception):
        pool.shutdown(wait=False, cancel_futures=True)


_POOLS: set = set()  # the pools of this process that are running now


def new_pool(workers: int) -> ProcessPoolExecutor:
    """A pool of ``workers`` processes started as this module starts them (:func:`context`,
    :func:`watch_parent`), known to :func:`kill_all` until :func:`retire`. The processes start
    at the first submit: callers submit within :func:`spawning`."""
    pool = ProcessPoolExecutor(max_workers=workers, mp_context=context(),
                               initializer=watch_parent, initargs=(os.getpid(),))
    _POOLS.add(pool)
    return pool


def retire(pool: ProcessPoolExecutor) -> None:
    """``pool`` is being shut down by its user: :func:`kill_all` no longer sees it."""
    _POOLS.discard(pool)


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
    fields = _stat(pid)
    return not fields or fields[0] != b"Z"  # no /proc: kill(pid, 0) is all there is


def watch_parent(owner_pid: int) -> None:
    """Worker initializer: ignore Ctrl-C and SIGTERM (the owner, the process whose pool this
    is, handles them and ends the workers) and exit when the owner dies (even by SIGKILL) or
    the process that started this worker does (the fork server, or the owner itself for a
    ``spawn`` worker), leaving no orphan computing a result nobody will store. What the worker
    holds now (the fork server's libraries) lives as long as it does: frozen, so that the full
    collections during its tasks do not walk it (a paper-table worker's: 0.8 s each)."""
    gc.freeze()
    for sig in _STOP_SIGNALS:  # already ignored since the start (see spawning), for good
        signal.signal(sig, signal.SIG_IGN)
    starter = os.getppid()

    def watch():
        while True:
            if os.getppid() != starter or not _alive(owner_pid):
                os._exit(1)
            time.sleep(0.5)
    threading.Thread(target=watch, daemon=True, name="clm-sim-parent-watch").start()

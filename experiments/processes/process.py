"""The life of a ``clm-sim`` process: how a command ends, whatever ends it.

:func:`run` calls one command and turns every way it can end into an exit code and at most one
line on stderr:

- a user mistake (:class:`clm_sim.errors.UserError`) or a file the checks did not foresee
  (``OSError``): the line, exit 2;
- Ctrl-C (exit 130), SIGTERM (exit 143), SIGHUP (129) or SIGQUIT (131): every ``finally``
  removes what it was writing, the workers are stopped, ``clm-sim: interrupted`` /
  ``terminated`` / ``hung up`` / ``quit``; a second signal ends the process at once;
- anything else is a bug of clm-sim: one line naming the command, its input and the internal
  error, with a hint to report it, exit 1 (the Python traceback only with ``--debug``).

A signal the process was started with ignored (:data:`IGNORED`) stays ignored.

A real process (``program=True``) receives its signals in a thread of its own
(:func:`receive_signals`) and ends without the interpreter's shutdown: after an interruption at
once (:func:`_exit_now`), after its command once the exit handlers have run
(:func:`_exit_done`). The modules it stops on the way, :mod:`experiments.processes.worker_life`
(worker processes, the fork server), :mod:`experiments.processes.workers` (the PGNN fit pool) and
:mod:`clm_sim.outdir` (temporary folders, locks), are imported here by name: all are light
(standard library only).
"""

from __future__ import annotations

import contextlib
import os
import signal
import sys
import threading
import traceback
from collections.abc import Callable

from clm_sim import outdir
from clm_sim.errors import UserError
from experiments.processes import worker_life, workers
EXIT_USER = 2  # a user mistake: bad input, a file that cannot be written
EXIT_BUG = 1  # an internal error (also: sweep tasks that failed, compare mismatches)
# The signals that end a command, each with its exit code (128 + the signal) and its line:
# SIGHUP (a closed terminal, a dropped ssh connection) and SIGQUIT (Ctrl-\\) end it as SIGTERM
# does, every temporary file removed and the workers ended, never as the default action would
# (at once, or with a core dump, leaving a ``.partial`` folder and the workers running).
CODES = {signal.SIGINT: 130, signal.SIGTERM: 128 + signal.SIGTERM}
WORDS = {signal.SIGINT: "interrupted", signal.SIGTERM: "terminated"}
for _name, _word in (("SIGHUP", "hung up"), ("SIGQUIT", "quit")):
    if hasattr(signal, _name):
        CODES[getattr(signal, _name)] = 128 + getattr(signal, _name)
        WORDS[getattr(signal, _name)] = _word
assert set(CODES) == worker_life._STOP_SIGNALS
ANSWER_S = 0.5  # s: how long the main thread may take to start unwinding after a signal


class Terminated(KeyboardInterrupt):
    """SIGTERM (or SIGHUP, SIGQUIT: ``signum``), raised like Ctrl-C so that every clean-up
    (temporary result folders, sweep workers) runs the same way."""

    def __init__(self, signum: int = signal.SIGTERM):
        super().__init__(signum)
        self.signum = signum


_said = False  # the line of an interruption is printed (a second signal prints no other)
_state = {"signalled": False, "done": False, "exiting": False, "signum": signal.SIGINT}
# Signals this process was started with ignored (a background job of a non-interactive shell,
# `nohup`-like wrappers): left ignored, as Python itself and the POSIX tools leave them; a
# Ctrl-C meant for the shell that started the command in the background does not stop it.
IGNORED = frozenset(sig for sig in CODES if signal.getsignal(sig) is signal.SIG_IGN)
_POKE = getattr(signal, "SIGUSR1", None)  # thread-directed, from the signal thread to main
_unwinding = threading.Event()  # set when the main thread has taken the first signal
_ENDING = threading.Lock()  # held by whoever ends the process: _exit_now or _end_now
_SAYING = threading.Lock()  # held while the interruption's line is written (:func:`_say`)


def _end_now(signum, frame):
    """A second Ctrl-C or SIGTERM while the first is being handled: end at once, whatever the
    clean-up was doing; the workers and the fork server are killed (with no lock taken:
    :func:`experiments.processes.worker_life.kill_now`), the temporary folder and lock removed
    first. Does nothing if the process is already being ended (:func:`_exit_now`)."""
    if not _ENDING.acquire(blocking=False):
        return
    try:
        # Each step on its own: one that fails (stderr a closed pipe, say) stops none of the
        # others, and the process ends whatever happens; it holds _ENDING, which the main
        # thread's own ending waits for.
        for step in (worker_life.kill_now, worker_life.remove_temp_dir, outdir.abandon,
                     lambda: _say(signum, lambda line: os.write(2, f"{line}\n".encode()))):
            with contextlib.suppress(BaseException):
                step()
    finally:
        os._exit(CODES[signum])


def _catch(handler) -> dict:
    """``handler`` for Ctrl-C and SIGTERM, except a signal ignored when the process started
    (:data:`IGNORED`); returns the handlers it replaced."""
    return {sig: signal.signal(sig, handler) for sig in CODES if sig not in IGNORED}


def _say(signum, write) -> None:
    """Write the interruption's one line through ``write`` unless it was written: the flag is
    tested and set under a lock, so a second signal that arrives while the main thread prints
    the line does not print it again. A handler that finds the lock held (the main thread is
    printing it) writes nothing."""
    global _said
    if not _SAYING.acquire(timeout=0.5):
        return
    try:
        if not _said:
            write(f"clm-sim: {WORDS[signum]}")
            _said = True
    finally:
        _SAYING.release()


def _signalled(signum, frame):
    """The first Ctrl-C or SIGTERM: unwind (every ``finally`` removes what it was writing); a
    second signal ends the process at once."""
    _unwinding.set()
    _catch(_end_now)
    raise KeyboardInterrupt if signum == signal.SIGINT else Terminated(signum)


def receive_signals() -> None:
    """A real process takes Ctrl-C and SIGTERM in a thread of its own: they are blocked in every
    other thread (blocked here before any library starts one), so none is lost to a library's
    thread or while workers start (:data:`experiments.processes.worker_life.SPAWNING`). The first is
    passed to the main thread as if it had come there (it unwinds the command); if the main thread
    has not taken it within ``ANSWER_S`` (inside a long computation), or on a second signal, or one
    after the command ended, this thread ends the process at once (:func:`_end_now`), as the
    main thread does if Python drops the signal in a finalizer (:func:`_end_on_dropped_signal`).
    Does nothing where the platform has no thread-directed signals."""
    if not hasattr(signal, "pthread_sigmask") or _POKE is None:
        return
    stops = set(CODES) - IGNORED
    if not stops:
        return
    signal.pthread_sigmask(signal.SIG_BLOCK, stops)
    # The main thread is poked with a signal of its own (a real one: it also ends a blocking
    # wait there), and takes it as the signal received.
    signal.signal(_POKE, lambda _, frame: _signalled(_state["signum"], frame))
    # Held with Ctrl-C and SIGTERM where a result folder is created or committed: the poke is
    # the signal as the main thread receives it.
    outdir.hold_also(_POKE)
    main = threading.main_thread().ident
    sys.unraisablehook = _end_on_dropped_signal(sys.unraisablehook, main)

    def receive():
        while True:
            signum = signal.sigwait(stops)
            if _state["exiting"]:
                continue  # the main thread is ending the process (under its own guard)
            if _state["signalled"] or _state["done"]:
                _end_now(signum, None)
                continue  # (only if the main thread is already ending the process)
            _state["signalled"], _state["signum"] = True, signum
            with worker_life.SPAWNING:
                signal.pthread_kill(main, _POKE)
            if not _unwinding.wait(ANSWER_S):
                # The main thread is inside a long call that releases the GIL (a simulation
                # kernel, a fit) and writes no file meanwhile: end from here.
                _end_now(signum, None)

    threading.Thread(target=receive, daemon=True, name="clm-sim-signals").start()


def _end_on_dropped_signal(hook, main: int):
    """``sys.unraisablehook`` that does not let Python drop the interruption: the poke's
    exception, raised while the main thread ran a finalizer (a ``__del__``, a weakref callback:
    a collection can run one anywhere), is printed as "Exception ignored" and dropped, and the
    command would run on to exit 0 as if no signal had come. The process ends from here, as
    when the main thread does not answer the poke (:func:`_end_now`; a second poke would be
    taken, and dropped, here again). Any other unraisable exception goes to ``hook``."""
    def unraisable(info):
        if isinstance(info.exc_value, KeyboardInterrupt) and _state["signalled"] \
                and not _state["done"] and threading.get_ident() == main:
            _end_now(_state["signum"], None)
        hook(info)
    return unraisable


def run(command: Callable[[], int], *, program: bool, name: str, source: str | None = None,
        debug: bool = False) -> int:
    """Call ``command`` and return its exit code, every ending turned into a code and at most
    one stderr line (module docstring). ``name``: the subcommand, ``source``: its input file,
    both for the line of an internal error; ``program``: a real process (ends at once after an
    interruption); ``debug``: an internal error also prints its traceback."""
    global _said
    _said = False
    main_thread = threading.current_thread() is threading.main_thread()
    previous = _catch(_signalled) if main_thread else {}
    code = None
    try:
        code = command()
        return code
    except UserError as exc:
        code = EXIT_USER
        print(f"clm-sim: error: {one_line(str(exc))}", file=sys.stderr)
        return code
    except KeyboardInterrupt as exc:
        sig = exc.signum if isinstance(exc, Terminated) else signal.SIGINT
        code = CODES[sig]
        workers.stop_fits()  # the PGNN fit pool (sweep workers end in workers.run_local)
        _say(sig, lambda line: print(line, file=sys.stderr, flush=True))
        return code
    except OSError as exc:  # a file the checks above did not foresee, one line
        code = EXIT_USER
        where = f"{exc.filename}: " if exc.filename else ""
        print(f"clm-sim: error: {where}{exc.strerror or exc}", file=sys.stderr)
        return code
    except (Exception, RecursionError) as exc:  # a bug of clm-sim: said, not hidden
        code = EXIT_BUG
        if debug:
            traceback.print_exc()
        on = f" on {source}" if source else ""
        print(f"clm-sim: internal error in '{name}'{on}: {type(exc).__name__}: "
              f"{one_line(str(exc), 300)}; this is a bug of clm-sim, please report it with the "
              f"command and its input"
              + ("" if debug else "; --debug shows the traceback"), file=sys.stderr)
        return code
    finally:
        if program and code in CODES.values():
            _exit_now(code)
        if program and main_thread:
            # Done: a late signal (results written, process ending) ends with its code.
            _state["done"] = True
            _catch(_end_now)
            if isinstance(code, int) and sys.getprofile() is None and sys.gettrace() is None:
                _exit_done(code)  # (a profiler or tracer writes its output after this returns)
        else:
            for sig, handler in previous.items():
                signal.signal(sig, handler)


def _exit_done(code: int) -> None:
    """End a process whose command has ended, without the interpreter's shutdown: the exit
    handlers run (the fit pool and the fork server are stopped, multiprocessing's and the
    libraries' clean-ups run), the standard streams are flushed, and the process exits. The
    shutdown that would follow (modules torn down, objects collected: 0.2 s with the heap
    frozen to 1.5 s without, torch loaded, ``benchmarks/bench_exit.py``) writes nothing of clm-sim's (every result file is
    closed and committed before the command returns) and ran where no thread of this process
    answered a signal any longer: a Ctrl-C or SIGTERM then was lost, and the command exited 0.
    Through the exit handlers the signal thread still answers (exit 130 or 143, one line)."""
    import atexit

    with contextlib.suppress(Exception):
        atexit._run_exitfuncs()
    with contextlib.suppress(Exception):
        sys.stdout.flush()
    with contextlib.suppress(Exception):
        sys.stderr.flush()
    os._exit(code)


def _exit_anyway(code: int) -> None:
    """:func:`_exit_now`'s guard: the process ends, its workers and fork server killed first
    (the main thread may be stopping the server, which must not outlive it stopped)."""
    try:
        with contextlib.suppress(BaseException):
            worker_life.kill_now()
    finally:
        os._exit(code)


def _exit_now(code: int) -> None:
    """End an interrupted process without interpreter shutdown, which may wait on pool threads
    (and so hang, or print a late traceback): only multiprocessing's own exit clean-up runs
    (it releases the pools' semaphores; the workers are already ended), under a one-second
    guard."""
    import multiprocessing.util

    _ENDING.acquire()  # not both this and a second signal's _end_now
    _state["exiting"] = True
    guard = threading.Timer(1.0, _exit_anyway, (code,))
    guard.daemon = True
    guard.start()
    with contextlib.suppress(Exception):
        worker_life.stop_server()  # the workers are ended: the fork server follows at once
    with contextlib.suppress(Exception):
        multiprocessing.util._exit_function()
    # Unlink the pools' semaphores (multiprocessing's resource tracker, which exits by itself
    # when this process has ended, then has nothing left to remove).
    with contextlib.suppress(Exception):
        multiprocessing.util._run_finalizers(0)
    with contextlib.suppress(Exception):
        sys.stdout.flush()
        sys.stderr.flush()
    os._exit(code)


def one_line(text: str, limit: int = 1000) -> str:
    """A message as one line of at most ``limit`` characters (a value quoted in it is cut)."""
    text = " ".join(text.split())
    return text if len(text) <= limit else text[:limit] + " ..."

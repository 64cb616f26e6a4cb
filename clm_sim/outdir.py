"""Result files and folders that appear whole or not at all.

One rule for every writer (records, sweep task results, tables, figures, result folders): build
the result under a temporary dot-name beside its target and rename it into place when complete,
so a reader, or a command resumed after a crash (``SIGKILL`` included), sees either the whole
result or none of it. A result folder is built in a temporary folder of its own run, under a lock
beside it that refuses a second writer, so it always holds exactly one run's files; an output
that cannot be written is one ``UserError`` line, checked before the work where it can be.
"""

from __future__ import annotations

import contextlib
import errno
import glob
import json
import os
import shutil
import stat
import tempfile
import threading
from collections.abc import Callable
from pathlib import Path

from clm_sim.errors import UserError


def atomic_write(path, data: bytes | str | Callable[[Path], object]) -> Path:
    """Write ``data`` to ``path`` so that no reader ever sees a partial file.

    ``data`` is the content (bytes, or text written as UTF-8) or a function that writes the
    file it is given (``lambda tmp: np.savetxt(tmp, ...)``; its name does not end in the
    target's suffix, so a writer that infers the format must be told it). The temporary file
    ``.<name>.tmp<pid>`` (never matched by ``*.json``-style globs of results) is flushed to disk,
    renamed over ``path`` and the rename made durable; on any error it is removed. Returns
    ``path``.
    """
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(f".{path.name}.tmp{os.getpid()}")
    try:
        if callable(data):
            data(tmp)
        else:
            tmp.write_bytes(data.encode() if isinstance(data, str) else data)
        with open(tmp, "rb+") as fh:
            os.fsync(fh.fileno())
        os.replace(tmp, path)
    finally:
        tmp.unlink(missing_ok=True)
    _fsync_dir(path.parent)
    return path


def _fsync_dir(folder: Path) -> None:
    # Makes the rename itself durable; not supported on every platform (e.g. Windows).
    try:
        fd = os.open(folder, os.O_RDONLY)
    except OSError:
        return
    try:
        os.fsync(fd)
    except OSError:
        pass
    finally:
        os.close(fd)


# errno values that mean "this place cannot take the output", whatever file was being written
_WRITE_ERRNOS = {errno.ENOSPC, errno.EROFS, errno.EACCES, errno.EPERM, errno.EDQUOT,
                 errno.ENAMETOOLONG, errno.ENOTDIR, errno.EISDIR, errno.EEXIST, errno.EFBIG,
                 errno.EMLINK}


def write_error(path, exc: OSError) -> UserError:
    """``exc`` (raised while writing the output ``path``) as one line naming the path and the
    cause, e.g. ``results/x: cannot write results/x/table.json: No space left on device``."""
    what = exc.strerror or type(exc).__name__
    where = f" {exc.filename}" if exc.filename else ""
    return UserError(f"{path}: cannot write{where}: {what}")


def _resolved(out: Path, given) -> Path:
    """``out`` with every link followed; a link that leads back to itself is one line."""
    try:
        return out.resolve()
    except (RuntimeError, OSError) as exc:  # Python < 3.13: RuntimeError; 3.13: OSError ELOOP
        if isinstance(exc, OSError) and exc.errno != errno.ELOOP:
            raise
        raise UserError(f"{given}: is a loop of symbolic links; choose another --out") from None


def check_inputs_outside(out, inputs) -> None:
    """Refuse an input file (a config, record or model the command reads) that lies inside the
    output folder ``out``: the folder is replaced as a whole, so the input would be deleted.
    ``None`` entries are skipped; an input that cannot be resolved is left to its reader."""
    given = out
    folder = _resolved(Path(out), given)
    for path in inputs:
        if path is None:
            continue
        try:
            where = Path(path).resolve()
        except (OSError, RuntimeError):
            continue
        if folder == where or folder in where.parents:
            raise UserError(f"{given}: holds the input {path}, which replacing the folder would "
                            f"delete; choose another --out or move the input out of it")


def check_writable(out, inputs=()) -> None:
    """Refuse, before any work, an output ``out`` that cannot be written: an existing file where a
    folder is needed, the current folder or one of its parents, a parent that is a file, a loop
    of symbolic links, a folder holding one of the ``inputs`` (:func:`check_inputs_outside`), or
    a place where nothing can be created (read-only, no permission, full disk). Writes nothing
    that stays: the probe is a temporary folder, removed at once."""
    given = out
    out = Path(out)
    try:
        resolved = _resolved(out, given)
        if out.exists() and not out.is_dir():
            raise UserError(f"{given}: exists and is a file, not a folder; choose another --out")
        if resolved == Path.cwd().resolve() or resolved in Path.cwd().resolve().parents:
            raise UserError(f"{given}: is the current folder or contains it; results go into a "
                            f"folder of their own; choose another --out")
        check_inputs_outside(out, inputs)
        anchor = resolved.parent
        while not anchor.exists():
            anchor = anchor.parent
        if not anchor.is_dir():
            raise UserError(f"{given}: {anchor} is a file, not a folder")
        with _signals_held():  # a Ctrl-C between the two would leave the probe behind
            os.rmdir(tempfile.mkdtemp(prefix=".clm-sim-probe-", dir=anchor))
    except OSError as exc:
        raise write_error(given, exc) from None


# Signals held with Ctrl-C and SIGTERM by :func:`_signals_held`. A command line process receives
# those two in a thread of its own and passes them to the main thread as another signal
# (experiments.processes.process.receive_signals), which registers it here with :func:`hold_also`:
# otherwise it would interrupt the main thread inside a block meant to be whole.
_HELD_ALSO: set[int] = set()
# Held by every block of :func:`_signals_held` and by :func:`abandon`: a process ended from
# another thread never removes a folder halfway through its creation or commit. Re-entrant: a
# handler that runs in the thread holding it (where a signal reached another thread of the
# process first) does not wait for itself.
_WRITING = threading.RLock()
_ABANDON_WAIT_S = 10.0  # s: how long abandon() waits for a block to end (a commit's rename)


def hold_also(signum: int) -> None:
    """Hold ``signum`` too while a result folder or lock file is created or committed."""
    _HELD_ALSO.add(signum)


@contextlib.contextmanager
def _signals_held():
    """Ctrl-C, SIGTERM, SIGHUP and SIGQUIT (and :data:`_HELD_ALSO`) wait until the block ends
    (main thread, POSIX), and :func:`abandon` waits for it in any thread."""
    import signal

    hold = (hasattr(signal, "pthread_sigmask")
            and threading.current_thread() is threading.main_thread())
    signals = {signal.SIGINT, signal.SIGTERM, *_HELD_ALSO,
               *(getattr(signal, name) for name in ("SIGHUP", "SIGQUIT") if hasattr(signal, name))}
    previous = signal.pthread_sigmask(signal.SIG_BLOCK, signals) if hold else None
    try:
        with _WRITING:
            yield
    finally:
        if hold:
            signal.pthread_sigmask(signal.SIG_SETMASK, previous)


# Temporary folders and lock files this process is writing now: removed by abandon().
_IN_PROGRESS: set[Path] = set()


def abandon() -> None:
    """Remove every temporary folder and lock file this process is writing now. For a process
    about to end at once (a second Ctrl-C during the clean-up of the first), where no ``finally``
    runs any more; best effort, never raises. A folder being created or committed in another
    thread is left to finish first (:func:`_signals_held`): a committed result stays whole."""
    held = _WRITING.acquire(timeout=_ABANDON_WAIT_S)
    try:
        _remove_in_progress()
    finally:
        if held:
            _WRITING.release()


def _remove_in_progress() -> None:
    for path in list(_IN_PROGRESS):
        with contextlib.suppress(OSError):
            if path.is_dir():
                shutil.rmtree(path, ignore_errors=True)
            else:
                path.unlink(missing_ok=True)


def _umask() -> int:
    mask = os.umask(0o022)
    os.umask(mask)
    return mask


# The manifest a result folder carries: every file and folder clm-sim wrote in it, each file
# with its size and SHA-256. A folder is replaced only when it holds exactly what its manifest
# lists, unchanged: nothing else is ever deleted (a user's file beside the results, a result
# the user edited, a folder of another program that happens to hold a file of the same name).
MANIFEST = ".clm-sim-manifest.json"
_MANIFEST_FORMAT = "clm-sim result folder"
_HASH_CHUNK = 1 << 20


def _sha256(path: Path) -> str:
    import hashlib

    digest = hashlib.sha256()
    fd = os.open(path, os.O_RDONLY | getattr(os, "O_NONBLOCK", 0) | getattr(os, "O_NOFOLLOW", 0))
    with os.fdopen(fd, "rb") as fh:
        if not stat.S_ISREG(os.fstat(fh.fileno()).st_mode):  # swapped for a FIFO since
            return "not a regular file"
        while chunk := fh.read(_HASH_CHUNK):
            digest.update(chunk)
    return digest.hexdigest()


def _regular(path: Path) -> bool:
    return stat.S_ISREG(path.lstat().st_mode)


def entries(folder: Path) -> tuple[list[str], list[str]]:
    """The folders and the other entries (files, links, anything) under ``folder``, as sorted
    relative POSIX paths, the manifest excluded; links are not followed."""
    folders, files = [], []
    for root, dirs, names in os.walk(folder, followlinks=False):
        rel = Path(root).relative_to(folder)
        for d in list(dirs):
            if (Path(root) / d).is_symlink():  # a link to a folder is an entry, not a folder
                dirs.remove(d)
                names.append(d)
            else:
                folders.append((rel / d).as_posix())
        files += [(rel / n).as_posix() for n in names if (rel / n).as_posix() != MANIFEST]
    return sorted(folders), sorted(files)


def write_manifest(folder: Path, what: str) -> None:
    """Record in ``folder`` every file and folder it holds as written by clm-sim (``what``: the
    kind of result, e.g. ``a simulation``)."""
    folders, files = entries(folder)
    # Only regular files are clm-sim's (a FIFO put in a folder would block the hash): anything
    # else is listed without a hash, so the folder is never taken for clm-sim's alone.
    listing = {"format": _MANIFEST_FORMAT, "what": what, "folders": folders,
               "files": {f: {"bytes": (folder / f).lstat().st_size,
                             "sha256": _sha256(folder / f) if _regular(folder / f) else None}
                         for f in files}}
    atomic_write(folder / MANIFEST, json.dumps(listing, indent=1) + "\n")


def manifest(out: Path) -> dict | None:
    """``out``'s manifest if it is one clm-sim wrote (a regular file of the expected shape),
    else ``None``."""
    path = out / MANIFEST
    try:
        if path.is_symlink() or not path.is_file() or path.stat().st_size > 1 << 26:
            return None
        listing = json.loads(path.read_text(encoding="utf-8"))
    except (OSError, ValueError):
        return None
    if not (isinstance(listing, dict) and listing.get("format") == _MANIFEST_FORMAT
            and isinstance(listing.get("what"), str) and isinstance(listing.get("files"), dict)
            and isinstance(listing.get("folders"), list)
            and all(isinstance(v, dict) for v in listing["files"].values())):
        return None
    return listing


def check_replaceable(out, given, what: str) -> None:
    """Refuse (``UserError``) to replace ``out`` unless it is absent, an empty folder, or a
    result folder of kind ``what`` that holds exactly the files its manifest lists, unchanged
    since clm-sim wrote them. The line names the first file that is not clm-sim's."""
    out = Path(out)
    if not out.is_dir() or not any(out.iterdir()):
        return
    listing = manifest(out)
    if listing is None:
        raise UserError(f"{given}: output folder exists and was not written by clm-sim (it has "
                        f"no {MANIFEST}); clm-sim replaces only its own results; choose another "
                        f"--out")
    if listing["what"] != what:
        raise UserError(f"{given}: output folder holds {listing['what']}, not {what}; "
                        f"choose another --out")
    folders, files = entries(out)
    for rel in folders:
        if rel not in listing["folders"]:
            raise UserError(f"{given}: holds the folder {rel}, which clm-sim did not write; "
                            f"nothing is replaced; move it or choose another --out")
    for rel in files:
        entry = listing["files"].get(rel)
        path = out / rel
        if entry is None or not _regular(path) or entry.get("sha256") is None:
            raise UserError(f"{given}: holds {rel}, which clm-sim did not write; nothing is "
                            f"replaced; move it or choose another --out")
        if path.stat().st_size != entry.get("bytes") or _sha256(path) != entry.get("sha256"):
            raise UserError(f"{given}: {rel} was changed after clm-sim wrote it; nothing is "
                            f"replaced; move it or choose another --out")


def check_output_folder(out, *, what: str, inputs=()) -> None:
    """What :func:`atomic_folder` will refuse, checked before the work: call it first so that a
    command never computes a result it cannot write."""
    check_writable(out, inputs)
    try:
        check_replaceable(Path(out), out, what)
    except OSError as exc:
        raise write_error(out, exc) from None


@contextlib.contextmanager
def output_lock(out: Path, given):
    """Hold an exclusive lock for writing ``out``: the file ``.<name>.lock`` beside it, removed on
    release. Refuses at once (``UserError``) when another process holds it."""
    try:
        import fcntl
    except ImportError:  # Windows: no advisory lock; the unique temporary folder still applies
        yield
        return
    path = out.with_name(f".{out.name}.lock")
    fd = None
    try:
        # Made, locked and recorded with Ctrl-C held, inside the try that removes the file: a
        # Ctrl-C that came between making and recording would leave it behind.
        with _signals_held():
            while True:
                fd = os.open(path, os.O_RDWR | os.O_CREAT, 0o644)
                try:
                    fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
                except OSError:
                    os.close(fd)
                    fd = None
                    raise UserError(f"{given}: another clm-sim command is writing this folder; "
                                    f"wait for it to finish or choose another --out") from None
                try:  # the holder before us may have removed the file after we opened it
                    same = os.stat(path).st_ino == os.fstat(fd).st_ino
                except FileNotFoundError:
                    same = False
                if same:
                    break
                os.close(fd)
                fd = None
            _IN_PROGRESS.add(path)
        yield
    finally:
        if fd is not None:
            try:
                path.unlink(missing_ok=True)  # while still locked: a waiting opener re-checks
            finally:
                _IN_PROGRESS.discard(path)
                os.close(fd)


@contextlib.contextmanager
def atomic_folder(out, *, what: str, subdirs: tuple[str, ...] = ("figures",), inputs=()):
    """Build a result folder in a temporary sibling and move it into place on success.

    ``out`` may already exist only as an empty folder or an earlier result of the same kind
    ``what`` that holds only the files its manifest lists, unchanged (:func:`check_replaceable`):
    it is then replaced; nothing clm-sim did not write is ever deleted. The new folder carries
    its own manifest (:data:`MANIFEST`). One command at a time writes a
    given ``out``: the others are refused (``.<name>.lock`` beside it). The temporary folder
    ``.<name>.partial-<pid>-<random>`` is this run's alone; the final rename is the only moment
    the result appears, so ``out`` always holds exactly one run's files. On any exception
    (``SIGTERM`` included: the CLI turns it into one) the temporary folder is removed, so an
    interrupted or failed run leaves nothing half-written; an ``OSError`` while writing becomes
    one ``UserError`` line naming the path. ``inputs``: the files the command reads, refused
    inside ``out`` (:func:`check_inputs_outside`).
    """
    given = out
    check_writable(out, inputs)
    out = _resolved(Path(out), given)
    try:
        out.parent.mkdir(parents=True, exist_ok=True)
        lock = output_lock(out, given)
        lock.__enter__()
    except OSError as exc:
        raise write_error(given, exc) from None
    tmp = None
    try:
        check_replaceable(out, given, what)
        # Under the lock every other temporary folder of this output is a killed run's.
        for stale in out.parent.glob(f".{glob.escape(out.name)}.partial*"):
            shutil.rmtree(stale, ignore_errors=True)
        with _signals_held():  # created and recorded at once: a Ctrl-C that came between
            tmp = Path(tempfile.mkdtemp(prefix=f".{out.name}.partial-{os.getpid()}-",
                                        dir=out.parent))  # the two would leave it behind
            _IN_PROGRESS.add(tmp)
        tmp.chmod(0o777 & ~_umask())  # mkdtemp's 0700 would hide the result from others
        for sub in subdirs:
            (tmp / sub).mkdir(parents=True)
        yield tmp
        write_manifest(tmp, what)
        check_replaceable(out, given, what)  # again: a writer without our lock may have come
        with _signals_held():  # a Ctrl-C now takes effect once the result is in place
            old = None
            if out.exists():  # moved aside, not deleted first: the result is never a mix
                old = out.with_name(f".{out.name}.partial-replaced-{os.getpid()}")
                out.rename(old)
            try:
                tmp.rename(out)
            except OSError:
                if old is not None:
                    old.rename(out)  # the earlier result stays
                raise
            _IN_PROGRESS.discard(tmp)
            tmp = None
            if old is not None:
                shutil.rmtree(old, ignore_errors=True)
            _fsync_dir(out.parent)
    except OSError as exc:
        if exc.errno not in _WRITE_ERRNOS:
            raise
        raise write_error(given, exc) from None
    finally:
        if tmp is not None:
            shutil.rmtree(tmp, ignore_errors=True)
            _IN_PROGRESS.discard(tmp)
        lock.__exit__(None, None, None)

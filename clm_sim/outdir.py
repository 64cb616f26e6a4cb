"""Result files and folders that appear whole or not at all.

One rule for every writer (records, sweep task results, tables, figures, result folders): build
the result under a temporary dot-name beside its target and rename it into place when complete,
so a reader, or a command resumed after a crash (``SIGKILL`` included), sees either the whole
result or none of it.
"""

from __future__ import annotations

import contextlib
import os
import shutil
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


@contextlib.contextmanager
def atomic_folder(out, *, marker: str, what: str, subdirs: tuple[str, ...] = ("figures",)):
    """Build a result folder in a temporary sibling and move it into place on success.

    ``out`` may already exist only if it holds ``marker`` (an earlier result of the same kind,
    which is replaced); ``what`` names that kind in the error. On any exception (``SIGTERM``
    included: the CLI turns it into one) the temporary folder is removed, so an interrupted or
    failed run leaves nothing half-written.
    """
    out = Path(out)
    if out.exists() and any(out.iterdir()) and not (out / marker).exists():
        raise UserError(f"{out}: output folder exists and does not hold {what}; "
                        f"choose another --out")
    tmp = out.with_name(f".{out.name}.partial")
    if tmp.exists():
        shutil.rmtree(tmp)
    try:
        tmp.mkdir(parents=True)
        for sub in subdirs:
            (tmp / sub).mkdir(parents=True)
        yield tmp
        if out.exists():
            shutil.rmtree(out)
        tmp.rename(out)
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        raise

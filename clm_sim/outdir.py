"""Result folders that appear whole or not at all."""

from __future__ import annotations

import contextlib
import shutil
from pathlib import Path

from clm_sim.errors import UserError


@contextlib.contextmanager
def atomic_folder(out, *, marker: str, what: str, subdirs: tuple[str, ...] = ("figures",)):
    """Build a result folder in a temporary sibling and move it into place on success.

    ``out`` may already exist only if it holds ``marker`` (an earlier result of the same kind,
    which is replaced); ``what`` names that kind in the error. On any exception the temporary
    folder is removed, so an interrupted or failed run leaves nothing half-written.
    """
    out = Path(out)
    if out.exists() and any(out.iterdir()) and not (out / marker).exists():
        raise UserError(f"{out}: output folder exists and does not hold {what}; "
                        f"choose another --out")
    tmp = out.with_name(f".{out.name}.partial")
    if tmp.exists():
        shutil.rmtree(tmp)
    tmp.mkdir(parents=True)
    for sub in subdirs:
        (tmp / sub).mkdir(parents=True)
    try:
        yield tmp
        if out.exists():
            shutil.rmtree(out)
        tmp.rename(out)
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        raise

"""Writing a run: NPZ (native: the signals plus ``meta`` as JSON), CSV (a header of signal
names; ``meta`` as JSON in a sidecar ``.meta.json``) and MATLAB ``.mat`` (column vectors,
``meta`` as a JSON string); ``clm-sim export`` (:func:`convert`)."""

from __future__ import annotations

import json
import os
from pathlib import Path

import numpy as np

from clm_sim.errors import UserError
from clm_sim.outdir import atomic_write
from clm_sim.records.read import load_record
from clm_sim.run import SIGNALS, Run


def save_npz(run: Run, path: Path) -> None:
    """Save as NPZ: one array per signal plus ``meta`` (JSON text), in a zip archive as
    ``numpy.savez_compressed`` writes it (``numpy.load`` reads it), each member deflated at
    level 1 where a trial on 64 kB from its middle (a run's start is often at rest) halves
    it, else stored: the signals of a closed loop (positions, forces) are float64 noise in
    their last bits, and deflating them saved about a fifth of their size for most of a paper
    table's writing time; time, errors and zero signals compress to a third or less."""
    import io
    import zipfile
    import zlib

    arrays = {"meta": np.array(json.dumps(run.meta, default=str)), **run.signals()}

    def write(tmp):
        with open(tmp, "wb") as fh, zipfile.ZipFile(fh, "w", allowZip64=True) as archive:
            for name, array in arrays.items():
                buf = io.BytesIO()
                np.lib.format.write_array(buf, np.asanyarray(array), allow_pickle=False)
                data = buf.getvalue()
                mid = max(0, len(data) // 2 - 32768)
                trial = data[mid:mid + 65536]
                deflate = len(zlib.compress(trial, 1)) < 0.5 * len(trial)
                archive.writestr(zipfile.ZipInfo(f"{name}.npy", (1980, 1, 1, 0, 0, 0)), data,
                                 compress_type=(zipfile.ZIP_DEFLATED if deflate
                                                else zipfile.ZIP_STORED), compresslevel=1)
    atomic_write(path, write)


def save_csv(run: Run, path: Path) -> None:
    """Save as CSV with a header of signal names; ``meta`` goes to ``<path>.meta.json``."""
    path = Path(path)
    data = np.column_stack([run.signals()[k] for k in SIGNALS])
    atomic_write(path, lambda tmp: np.savetxt(tmp, data, delimiter=",", header=",".join(SIGNALS),
                                              comments="", fmt="%.17g"))
    atomic_write(path.with_name(path.name + ".meta.json"),
                 json.dumps(run.meta, indent=1, default=str))


def save_mat(run: Run, path: Path) -> None:
    """Save as MATLAB .mat: column vectors named as the signals, ``meta`` as a JSON string."""
    import scipy.io

    def write(tmp):
        with open(tmp, "wb") as fh:
            scipy.io.savemat(fh, {**{k: v[:, None] for k, v in run.signals().items()},
                                  "meta": json.dumps(run.meta, default=str)})
    atomic_write(path, write)


def convert(path, to: str, out=None) -> tuple[Path, int]:
    """``clm-sim export``: the record at ``path`` written as ``to`` (``csv`` or ``mat``) to
    ``out`` (default: ``path`` with that suffix); returns the file and its sample count. Writes
    no file that exists (the input above all: a CSV exported over itself would lose every column
    beyond the signals), so nothing of the user's is ever overwritten."""
    out = Path(out) if out else Path(path).with_suffix("." + to)
    if out.suffix.lower() != "." + to:
        raise UserError(f"{out}: --to {to} needs a .{to} file name")
    for target in (out, out.with_name(out.name + ".meta.json")) if to == "csv" else (out,):
        if target.exists() or target.is_symlink():
            same = target.exists() and Path(path).exists() and os.path.samefile(target, path)
            raise UserError(f"{target}: " + ("is the input; clm-sim export writes a new file"
                                             if same else "exists; clm-sim export does not "
                                             "write over a file") +
                            "; choose another --out or move the file")
    run = load_record(path)
    (save_csv if to == "csv" else save_mat)(run, out)
    return out, len(run)

"""Loading a record: a measured or simulated run from its file, its columns mapped to the
signals, scaled to SI units and checked (:func:`load_record`, in named steps); the
``--columns``/``--scale`` pairs of a command (:func:`parse_pairs`)."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from clm_sim.errors import UserError
from clm_sim.records.checks import check_magnitudes, numbers, scaled, uniform_step
from clm_sim.records.files import MAX_RECORD_BYTES, read_columns
from clm_sim.run import SIGNALS, Run

REQUIRED = ("t", "r", "y", "u")
MIN_SAMPLES = 200


def load_record(path, columns: dict[str, str] | None = None,
                scale: dict[str, float] | None = None, min_samples: int = MIN_SAMPLES) -> Run:
    """Load a measured or simulated record and check it.

    Parameters
    ----------
    path : str or Path
        CSV with a header, NPZ, or MAT file holding at least ``t, r, y, u`` (s, m, m, N).
    columns : dict, optional
        Map from signal name to the name in the file, e.g. ``{"y": "qm", "u": "vir"}``.
    scale : dict, optional
        Factor per signal applied after loading, e.g. ``{"u": 35.15}`` (V to N); a value may
        also name a scalar variable of the file (``{"u": "gtau"}``).
    min_samples : int
        Shortest record accepted.

    Returns
    -------
    Run
        The record; ``meta["source"]`` names the file.

    Raises
    ------
    UserError
        One line naming the file and the column, for a missing column, NaN or inf, time
        stamps that are not strictly increasing and uniform (the rounding of their stored
        type allowed), or a record that is too short; for units off by orders of magnitude:
        a sample time above ``MAX_TS`` (t in ms) or below ``MIN_TS``, a position beyond
        ``MAX_POSITION_M`` (y in mm) or a force beyond ``MAX_FORCE_N``. A variable that is not
        numbers (text, MATLAB cells, structs, sparse matrices, complex values with an
        imaginary part) is refused by name; so is a ``columns`` or ``scale`` name that is no
        signal, a mapped column the file lacks, and a scale whose result squares to inf or 0.

    Examples
    --------
    A logger's file with its own column names, the force in volts:

    >>> import numpy as np
    >>> from clm_sim import load_record
    >>> t = np.arange(400) * 1e-3
    >>> table = np.column_stack([t, np.sin(t), np.sin(t), 0.1 * np.cos(t)])
    >>> np.savetxt("log.csv", table, delimiter=",", header="time,ref,pos,volt", comments="")
    >>> record = load_record("log.csv", columns={"t": "time", "r": "ref", "y": "pos",
    ...                                          "u": "volt"}, scale={"u": 35.15})
    >>> len(record), record.ts, round(float(record.u[0]), 3)   # samples, s, N
    (400, 0.001, 3.515)
    >>> load_record("log.csv")
    Traceback (most recent call last):
    ...
    clm_sim.errors.UserError: log.csv: missing column 't' (signal t); columns present: ...time, volt
    """
    path = _regular_file(Path(path))
    raw, file_meta = read_columns(path)
    source = _Source(path, raw, dict(columns or {}))
    source.check_mapping()
    signals = source.signals()
    for name, factor in (scale or {}).items():
        signals[name] = source.scaled(signals, name, factor)
    _check_samples(source, signals, min_samples)
    t_column = source.column("t")
    ts = uniform_step(signals["t"], np.asarray(raw[t_column]).ravel(),
                      f"{path}: column {t_column!r}")
    check_magnitudes(path, signals, ts, {name: source.column(name) for name in REQUIRED})
    return Run(**signals, meta={**file_meta, "source": str(path)})


def _regular_file(path: Path) -> Path:
    """``path``, refused unless it is a regular file of at most ``MAX_RECORD_BYTES``."""
    if not path.exists():
        raise UserError(f"{path}: file not found")
    if not path.is_file():  # a device (/dev/zero), a pipe or a folder never ends or is no record
        raise UserError(f"{path}: not a regular file; a record is a .csv, .npz or .mat file")
    size = path.stat().st_size
    if size > MAX_RECORD_BYTES:
        raise UserError(f"{path}: {size / 2 ** 30:.3g} GB, above the "
                        f"{MAX_RECORD_BYTES / 2 ** 30:g} GB a record may have (1e7 samples of "
                        f"t, r, y, u as CSV are ~0.8 GB)")
    return path


@dataclass(frozen=True)
class _Source:
    """A record file's variables ``raw`` and the map ``columns`` from signal to variable name."""

    path: Path
    raw: dict
    columns: dict[str, str]

    def column(self, name: str) -> str:
        """The file's name of signal ``name``."""
        return self.columns.get(name, name)

    @property
    def have(self) -> str:
        """The file's variables, for an error line (a .mat file may hold hundreds)."""
        names = sorted(self.raw)
        return (", ".join(names[:30])
                + (f", ... ({len(names) - 30} more)" if len(names) > 30 else "") or "none")

    def known(self, name: str, what: str) -> None:
        """Refuse a ``name`` that is no signal: a typo would silently leave a signal out (or
        at its default)."""
        if name not in SIGNALS:
            raise UserError(f"{self.path}: cannot {what}: no such signal; the signals are "
                            f"{', '.join(SIGNALS)}")

    def check_mapping(self) -> None:
        """Every mapped signal is a signal whose column the file has, and no column is read
        as two signals (y read as r too gives a zero error)."""
        for name, key in self.columns.items():
            self.known(name, f"map {name!r} to a column")
            if key not in self.raw:
                raise UserError(f"{self.path}: missing column {key!r} (signal {name}); "
                                f"columns present: {self.have}")
        read_by: dict[str, str] = {}
        for name in SIGNALS:
            key = self.column(name)
            if key in self.raw and key in read_by:
                raise UserError(f"{self.path}: signals {read_by[key]} and {name} would both be "
                                f"read from column {key!r}; map each signal to a column of its "
                                f"own")
            read_by.setdefault(key, name)

    def signals(self) -> dict[str, np.ndarray]:
        """The signals the file has, as 1-D float64 arrays; a required one missing is refused."""
        out = {}
        for name in SIGNALS:
            key = self.column(name)
            if key not in self.raw:
                if name in REQUIRED:
                    raise UserError(f"{self.path}: missing column {key!r} (signal {name}); "
                                    f"columns present: {self.have}")
                continue
            value = numbers(self.raw[key], self.path, key)
            if value.ndim == 0:
                raise UserError(f"{self.path}: column {key!r} is a single number, expected a "
                                f"column of samples")
            if value.ndim > 1:
                if min(value.shape) != 1:
                    raise UserError(f"{self.path}: column {key!r} must be a vector, got shape "
                                    f"{value.shape}")
                value = value.ravel()
            out[name] = value
        return out

    def scaled(self, signals: dict[str, np.ndarray], name: str, factor) -> np.ndarray:
        """Signal ``name`` times ``factor``: a number, or the name of a scalar variable of
        the file."""
        path = self.path
        self.known(name, f"scale {name!r}")
        if name not in signals:
            raise UserError(f"{path}: cannot scale {name!r}: no column {name!r} in the file "
                            f"(map it to one: {name}=COLUMN); columns present: {self.have}")
        if isinstance(factor, str):
            value = self.raw.get(factor)
            if not isinstance(value, np.ndarray) or value.dtype.kind not in "biufc" \
                    or np.size(value) != 1:
                raise UserError(f"{path}: scale for {name!r} names {factor!r}, which is not a "
                                f"scalar number in the file")
            factor = float(numbers(value, path, factor).ravel()[0])
        if not (np.isfinite(factor) and factor != 0):
            raise UserError(f"{path}: scale for {name!r} is {factor:g}; expected a finite, "
                            f"non-zero factor")
        return scaled(signals[name], float(factor), path, name)


def _check_samples(source: _Source, signals: dict[str, np.ndarray], min_samples: int) -> None:
    """Every signal as long as ``t``, the required ones finite, at least ``min_samples``."""
    n = len(signals["t"])
    for name, value in signals.items():
        if len(value) != n:
            raise UserError(f"{source.path}: column {source.column(name)!r} has {len(value)} "
                            f"samples, t has {n}")
        bad = ~np.isfinite(value)
        if bad.any() and name in REQUIRED:
            raise UserError(f"{source.path}: column {source.column(name)!r} holds NaN or inf "
                            f"(first at row {int(np.argmax(bad))})")
    if n < min_samples:
        raise UserError(f"{source.path}: record too short: {n} samples, need at least "
                        f"{min_samples}")


def parse_pairs(text: str | None, option: str, number: bool) -> dict:
    """``"y=qm,u=vir"`` -> ``{"y": "qm", "u": "vir"}``: the ``--columns`` and ``--scale`` of a
    command (values as numbers where they parse and ``number``); ``option`` names it in errors."""
    out = {}
    for item in filter(None, (text or "").split(",")):
        key, sep, value = item.partition("=")
        if not sep or not key.strip() or not value.strip():
            raise UserError(f"{option}: expected NAME=VALUE pairs separated by commas, "
                            f"got {item!r}")
        key, value = key.strip(), value.strip()
        if key in out:  # the last one would win silently
            raise UserError(f"{option}: {key!r} given twice; give each signal once")
        if number:
            try:
                value = float(value)
            except ValueError:
                pass
        out[key] = value
    return out

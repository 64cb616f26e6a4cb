"""The logged run: one record type for simulated and measured data, and its files.

Every signal is a 1-D float64 array of the same length, sampled at ``t`` (s):
``r`` reference (m), ``y`` measured position (m), ``y_true`` true position (m, NaN if unknown),
``u`` total force applied to the plant (N), ``u_fb`` feedback part, ``u_ff`` feedforward part,
``dither`` injected excitation (N, NaN if unknown), ``e = r - y`` (m). ``meta`` holds the resolved
config, seed and versions.

Files: NPZ (native, signals plus ``meta`` as JSON), CSV (header of column names; ``meta`` as JSON in
a sidecar ``.meta.json``), and MATLAB ``.mat`` (signals as column vectors, ``meta`` as a JSON string).
Measured records need only ``t, r, y, u``; columns can be renamed and scaled on load.
"""

from __future__ import annotations

import json
import os
import re
import warnings
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from clm_sim.errors import UserError
from clm_sim.outdir import atomic_write

SIGNALS = ("t", "r", "y", "y_true", "u", "u_fb", "u_ff", "dither", "e")
REQUIRED = ("t", "r", "y", "u")
MIN_SAMPLES = 200
MAX_TS = 0.01  # s: a servo record sampled slower than 100 Hz has its time stamps in ms
MIN_TS = 1e-7  # s: no servo samples faster than 10 MHz; such time stamps are in other units
UNIFORM_RTOL = 1e-3  # a step may differ from the mean step by this share, beyond the rounding
COARSE_STAMPS = 0.01  # stamps whose type's spacing exceeds this share of a step cannot show it
MAX_POSITION_M = 10.0  # m: longer than any linear-motor stroke; larger values are in mm or counts
MAX_FORCE_N = 1e6  # N: 50 times the peak force of the largest linear motors; larger is not N
MAX_RECORD_BYTES = 2 ** 30  # a record file (or an .npz's arrays) larger is refused before reading
GENFROMTXT_BYTES = 50 * 2 ** 20  # CSVs with empty cells are read by genfromtxt up to this size
# A scaled signal's peak must lie here (about 1.5e-154 to 1.3e154) so its squares are finite and
# not zero: a scale outside gives a fit of NaN, not a refusal.
SQUARE_RANGE = (float(np.sqrt(np.finfo(float).tiny)), float(np.sqrt(np.finfo(float).max)))


@dataclass(frozen=True)
class Run:
    """A logged closed-loop run: one record type for simulated and measured data.

    Every signal is a 1-D float64 array of one length, sampled at ``t``; a signal that is not
    known (``None``) is NaN (``e`` defaults to ``r - y``). ``ts`` is the sample time from the
    time stamps; ``mae``, ``rms`` and ``max`` are the tracking-error metrics (m).
    ``clm_sim.record.save_npz``, ``save_csv`` and ``save_mat`` write one; :func:`load_record`
    reads one back.

    Parameters
    ----------
    t : ndarray
        Time stamps, s.
    r : ndarray
        Reference position, m.
    y : ndarray
        Measured position, m.
    u : ndarray
        Total force applied to the plant, N.
    y_true : ndarray, optional
        True position, m (a simulation knows it).
    u_fb, u_ff : ndarray, optional
        Feedback and feedforward parts of ``u``, N.
    dither : ndarray, optional
        Injected excitation, N.
    e : ndarray, optional
        Tracking error ``r - y``, m.
    meta : dict
        The resolved config, seed and versions of a simulated run; the source of a loaded one.

    Raises
    ------
    ValueError
        A signal that is not 1-D or not of the length of ``t``.

    Examples
    --------
    >>> import numpy as np
    >>> from clm_sim import Run
    >>> t = np.arange(5) * 1e-4
    >>> run = Run(t=t, r=np.zeros(5), y=np.full(5, 1e-6), u=np.ones(5))
    >>> run.ts, run.mae                     # s, m
    (0.0001, 1e-06)
    >>> bool(np.isnan(run.dither).all())    # not known
    True
    """

    t: np.ndarray
    r: np.ndarray
    y: np.ndarray
    u: np.ndarray
    y_true: np.ndarray | None = None
    u_fb: np.ndarray | None = None
    u_ff: np.ndarray | None = None
    dither: np.ndarray | None = None
    e: np.ndarray | None = None
    meta: dict = field(default_factory=dict)

    def __post_init__(self):
        n = np.shape(self.t)[0] if np.ndim(self.t) == 1 else -1
        for name in SIGNALS:
            value = getattr(self, name)
            if value is None:
                value = self.r - self.y if name == "e" else np.full(n, np.nan)
            value = np.ascontiguousarray(value, dtype=np.float64)
            if value.ndim != 1 or value.shape[0] != n:
                raise ValueError(f"run signal {name!r} must be 1-D of length {n}, "
                                 f"got shape {value.shape}")
            object.__setattr__(self, name, value)

    def __repr__(self) -> str:
        known = [k for k in SIGNALS[1:] if not np.all(np.isnan(getattr(self, k)))]
        where = self.meta.get("run") or self.meta.get("source")
        timing = f", ts={self.ts:g} s, {self.t[-1] - self.t[0]:.4g} s" if len(self) > 1 else ""
        return (f"Run({len(self)} samples{timing}; {', '.join(known)}"
                + (f"; {str(where)[:60]}" if where else "") + ")")

    @property
    def ts(self) -> float:
        """Sample time (s), from the time stamps."""
        return float((self.t[-1] - self.t[0]) / (len(self.t) - 1))

    def __len__(self) -> int:
        return len(self.t)

    @property
    def mae(self) -> float:
        """Mean absolute tracking error ``mean |e|`` (m)."""
        return float(np.mean(np.abs(self.e)))

    @property
    def rms(self) -> float:
        """Root-mean-square tracking error (m)."""
        return float(np.sqrt(np.mean(self.e ** 2)))

    @property
    def max(self) -> float:
        """Largest absolute tracking error (m)."""
        return float(np.max(np.abs(self.e)))

    def metrics(self) -> dict[str, float]:
        """``{"mae", "rms", "max"}`` of the tracking error (m)."""
        return {"mae": self.mae, "rms": self.rms, "max": self.max}

    def signals(self) -> dict[str, np.ndarray]:
        return {name: getattr(self, name) for name in SIGNALS}

    def moved_origin(self, offset: float) -> "Run":
        """The run seen from an origin ``offset`` m lower: ``y``, ``r`` and ``y_true`` plus
        ``offset``; ``e`` and the forces unchanged. Registers a record whose incremental
        encoder was homed elsewhere to another record's frame."""
        signals = self.signals()
        for name in ("y", "r", "y_true"):
            signals[name] = signals[name] + float(offset)
        return Run(**signals, meta=self.meta)

    def slice(self, start: int, stop: int | None = None) -> "Run":
        """The samples ``start:stop`` as a new run (same meta)."""
        return Run(**{k: v[start:stop] for k, v in self.signals().items()}, meta=self.meta)


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


# The formats a record is read from (by suffix, any case): what no model or config file is.
RECORD_SUFFIXES = (".csv", ".npz", ".mat")


def _read_columns(path: Path) -> tuple[dict[str, np.ndarray], dict]:
    """The file's variables (arrays as stored, checked by :func:`_numbers` when used) and its
    ``meta`` (a JSON object, else empty). Every failure is one ``UserError`` line."""
    suffix = path.suffix.lower()
    try:
        if suffix == ".csv":
            # utf-8-sig: Excel's "CSV UTF-8" starts with a byte-order mark
            with open(path, encoding="utf-8-sig") as fh:
                header = fh.readline().strip()
            if not header:
                raise UserError(f"{path}: empty file, expected a CSV header such as 't,r,y,u'")
            names = [h.strip().lstrip("#").strip().strip('"').strip() for h in header.split(",")]
            if len(names) == 1 and ";" in header:
                raise UserError(_semicolons(path, header))
            if any(n and n[0] in "0123456789-+." for n in names):
                raise UserError(f"{path}: the first line must be a header of column names "
                                f"(t, r, y, u), got numbers")
            seen: dict[str, int] = {}
            for i, n in enumerate(names):
                if n in seen:  # a dict of columns would keep the last one silently
                    raise UserError(f"{path}: the header names column {n!r} twice (columns "
                                    f"{seen[n] + 1} and {i + 1}); give every column its own "
                                    f"name")
                seen[n] = i
            data = _read_csv_rows(path, names)
            if data.size == 0:
                raise UserError(f"{path}: no data rows after the header")
            if data.shape[1] != len(names):
                raise UserError(f"{path}: header has {len(names)} columns, rows have "
                                f"{data.shape[1]}" + (DECIMAL_COMMAS if _commas(path, names, data)
                                                      else ""))
            return {n: data[:, i] for i, n in enumerate(names)}, {}
        if suffix == ".npz":
            # Our own handle, closed even when a truncated archive makes np.load raise.
            with open(path, "rb") as fh:
                z = np.load(fh, allow_pickle=False)
                if not isinstance(z, np.lib.npyio.NpzFile):  # one array saved by np.save
                    raise UserError(f"{path}: not an .npz archive (it holds a single .npy "
                                    f"array); save the signals by name with numpy.savez")
                with z:
                    unpacked = sum(i.file_size for i in z.zip.infolist())
                    if unpacked > MAX_RECORD_BYTES:  # a small archive may unpack to terabytes
                        raise UserError(f"{path}: its arrays unpack to "
                                        f"{unpacked / 2 ** 30:.3g} GB, above the "
                                        f"{MAX_RECORD_BYTES / 2 ** 30:g} GB of a record")
                    raw = {k: np.asarray(z[k]) for k in z.files}
            return raw, _meta(raw.pop("meta", None))
        if suffix == ".mat":
            import scipy.io
            d = scipy.io.loadmat(path)
            return {k: v for k, v in d.items() if not k.startswith("__")}, {}
    except UserError:
        raise
    except FileNotFoundError:
        raise UserError(f"{path}: file not found") from None
    except Exception as exc:  # a truncated or foreign file (any error), said in one line
        raise UserError(f"{path}: cannot read as {suffix[1:].upper()} ({_first_line(exc)})") \
            from None
    raise UserError(f"{path}: unknown record format {suffix!r}; expected .csv, .npz or .mat")


def _read_csv_rows(path: Path, names: list[str]) -> np.ndarray:
    """The numbers below a CSV's header, (rows, columns) float64. ``np.loadtxt`` reads in C
    into the final array (about the array's size in memory; ``genfromtxt`` needs ~9 times the
    file); where it fails, the first cell that is no number (or the first row of another
    width) is refused by line and column, and only a file whose failure is an empty cell (read
    as NaN and refused by name later) is read by the slower ``genfromtxt``, up to
    ``GENFROMTXT_BYTES``."""
    try:
        with open(path, encoding="utf-8-sig") as fh:
            fh.readline()
            with warnings.catch_warnings():  # "empty input" is reported by the caller
                warnings.simplefilter("ignore", UserWarning)
                return np.loadtxt(fh, delimiter=",", dtype=float, ndmin=2)
    except ValueError:
        _refuse_cell(path, names)
        if path.stat().st_size > GENFROMTXT_BYTES:
            raise
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", UserWarning)
        return np.genfromtxt(path, delimiter=",", skip_header=1, dtype=float,
                             invalid_raise=True, ndmin=2, encoding="utf-8")


DECIMAL_COMMAS = (" (decimal commas? a record's CSV has ',' between columns and '.' as the "
                  "decimal mark, e.g. 0.0001,0,0,8.96)")
_DECIMAL_COMMA = re.compile(r"[-+]?\d+,\d+(?:[eE][-+]?\d+)?")


def _line(path: Path, number: int) -> str:
    """Line ``number`` (1 = the header) of a text file, '' past its end."""
    with open(path, encoding="utf-8-sig") as fh:
        for k, line in enumerate(fh, 1):
            if k == number:
                return line.rstrip("\r\n")
    return ""


def _commas(path: Path, names: list[str], data: np.ndarray) -> bool:
    """Whether rows wider than the header may be numbers with decimal commas: no '.' in the
    first row, and a digit, comma, digit in it."""
    line = _line(path, 2)
    return data.shape[1] > len(names) and "." not in line and bool(_DECIMAL_COMMA.search(line))


def _semicolons(path: Path, header: str) -> str:
    """The refusal of a CSV whose header separates its names by ';' (a spreadsheet's CSV in a
    locale with decimal commas), naming the first decimal comma of its first row if any."""
    comma = _DECIMAL_COMMA.search(_line(path, 2))
    found = f" and line 2 has decimal commas ({comma.group()!r})" if comma else ""
    return (f"{path}: cannot read as CSV: line 1 separates its names by ';' ({header[:60]!r})"
            f"{found}; a record's CSV has ',' between columns and '.' as the decimal mark, "
            f"e.g. 0.0001,0,0,8.96")


def _refuse_cell(path: Path, names: list[str]) -> None:
    """Refuse the first data cell of a CSV that is not a number (an empty one is let through:
    it is NaN, refused by column later), or the first row with another number of cells than
    the header, by line (1 = the header) and column."""
    with open(path, encoding="utf-8-sig") as fh:
        fh.readline()
        for k, line in enumerate(fh, 2):
            line = line.split("#", 1)[0].strip()
            if not line:
                continue
            cells = line.split(",")
            for j, cell in enumerate(cells):
                try:
                    float(cell) if cell.strip() else None
                except ValueError:
                    name = f" ({names[j]})" if j < len(names) and names[j] else ""
                    hint = DECIMAL_COMMAS if ";" in cell else ""
                    raise UserError(f"{path}: cannot read as CSV: line {k}, column {j + 1}"
                                    f"{name}: {cell.strip()[:40]!r} is not a number{hint}") \
                        from None
            if len(cells) != len(names):
                hint = DECIMAL_COMMAS if (len(cells) > len(names) and "." not in line
                                          and _DECIMAL_COMMA.search(line)) else ""
                raise UserError(f"{path}: cannot read as CSV: line {k} has {len(cells)} cells, "
                                f"the header {len(names)}{hint}")


def _coarse_stamps(t: np.ndarray, ts: float, resolution: float, dtype) -> str:
    """Why time stamps ``t`` (s, step ``ts``) cannot resolve their step better than
    ``resolution`` (s), and the cure: float64, and stamps from the first sample."""
    top = float(np.max(np.abs(t)))
    cures = [] if dtype == np.float64 or dtype.kind not in "fc" else ["as float64"]
    if abs(float(t[0])) > float(t[-1] - t[0]):  # an offset (Unix-epoch seconds) costs digits
        cures.append("from the first sample (t - t[0])")
    return (f"its {dtype} time stamps reach {top:.3g} s, where they are {resolution:.2g} s apart "
            f"({100 * resolution / ts:.2g} % of the {ts:.3g} s step)"
            + (f"; store t {' or '.join(cures)}" if cures else ""))


def _uniform_step(t: np.ndarray, stamps: np.ndarray, where: str) -> float:
    """The sample time (s) of time stamps ``t`` (s, as scaled from ``stamps``, the column as
    stored), refused (``where``: the file and column) unless strictly increasing and uniform:
    every step within ``UNIFORM_RTOL`` of the mean step beyond the rounding of the stored type
    at that step (each stamp lies within half its spacing of the true time, so a step within
    one; integers are exact up to 2**53), plus float64's own rounding of the scaled times.
    Stamps whose spacing exceeds ``COARSE_STAMPS`` of a step cannot show it: refused, naming
    the type and the offset (float32 or Unix-epoch stamps are rounded, not uneven)."""
    top = float(np.max(np.abs(stamps)))
    scale = float(np.max(np.abs(t))) / top if top > 0 else 1.0

    def spacing(values: np.ndarray) -> np.ndarray:  # s, as scaled
        if stamps.dtype.kind in "fc":
            return np.spacing(np.abs(values).astype(stamps.dtype)).astype(np.float64) * scale
        magnitude = np.abs(values).astype(np.float64)
        return np.where(magnitude >= 2.0 ** 53, np.spacing(magnitude), 0.0) * scale

    dt = np.diff(t)
    resolution = float(spacing(np.array([top], dtype=stamps.dtype))[0])  # at the largest
    ts = (t[-1] - t[0]) / (len(t) - 1)
    if not (dt > 0).all():
        coarse = (f"; {_coarse_stamps(t, ts, resolution, stamps.dtype)}"
                  if ts > 0 and resolution > UNIFORM_RTOL * ts else "")
        raise UserError(f"{where} must be strictly increasing (row "
                        f"{int(np.argmax(dt <= 0)) + 1} is not{coarse})")
    coarse = _coarse_stamps(t, ts, resolution, stamps.dtype)
    ends = np.maximum(np.abs(stamps[:-1]), np.abs(stamps[1:]))
    rounding = spacing(ends) + np.spacing(np.maximum(np.abs(t[:-1]), np.abs(t[1:])))
    excess = np.abs(dt - ts) - (UNIFORM_RTOL * ts + rounding)
    if (excess > 0).any():
        # The type is to blame where the worst step's own rounding is of its size.
        k = int(np.argmax(excess))
        blame = (rounding[k] > UNIFORM_RTOL * ts
                 and abs(dt[k] - ts) <= UNIFORM_RTOL * ts + 4 * rounding[k])
        raise UserError(f"{where} is not uniformly sampled (steps from {dt.min():.6g} to "
                        f"{dt.max():.6g} s" + (f"; {coarse}" if blame else "") + ")")
    if resolution > COARSE_STAMPS * ts:
        raise UserError(f"{where} cannot show a uniform sampling: {coarse}")
    return float(ts)


def _first_line(exc: BaseException) -> str:
    text = str(exc).splitlines()[0] if str(exc) else type(exc).__name__
    return text if len(text) <= 200 else text[:200] + "..."


def _meta(value) -> dict:
    """An NPZ ``meta`` entry: a JSON object, else nothing (a record's meta is informative)."""
    try:
        meta = json.loads(str(value)) if value is not None and np.ndim(value) == 0 else {}
    except (ValueError, RecursionError):
        return {}
    return meta if isinstance(meta, dict) else {}


_KINDS = {"U": "text", "S": "bytes", "O": "cells or objects", "V": "a struct or record",
          "M": "dates", "m": "time spans"}


def _numbers(value, path: Path, key: str) -> np.ndarray:
    """``value`` as a float64 array, or one line saying what the variable ``key`` holds
    instead (text, a MATLAB cell, struct or sparse matrix, complex numbers)."""
    if not isinstance(value, np.ndarray):  # scipy.sparse from a MATLAB sparse matrix
        raise UserError(f"{path}: variable {key!r} is {type(value).__name__}, expected a "
                        f"dense numeric array (store it with full(...) in MATLAB)")
    kind = value.dtype.kind
    if kind in _KINDS:
        raise UserError(f"{path}: variable {key!r} holds {_KINDS[kind]}, expected numbers")
    if kind == "c":
        if np.any(value.imag != 0):
            raise UserError(f"{path}: variable {key!r} is complex; expected real numbers")
        value = value.real
    return np.asarray(value, dtype=np.float64)


def _scaled(value: np.ndarray, factor: float, path: Path, name: str) -> np.ndarray:
    """``value * factor``, refused in one line where the factor takes the signal out of the
    range in which its squares (every fit's residual and norm) are finite and non-zero."""
    with np.errstate(over="ignore", under="ignore"):
        scaled = value * factor
    finite = np.isfinite(value)
    peak = float(np.max(np.abs(scaled[finite]), initial=0.0))
    if not np.isfinite(scaled[finite]).all() or peak > SQUARE_RANGE[1]:
        raise UserError(f"{path}: scale for {name!r} is {factor:g}; it takes {name} to "
                        f"{peak:.3g}, beyond float64 once squared; expected a unit factor "
                        f"(e.g. 35.15 for V to N, 0.001 for mm to m)")
    if np.any(value[finite]) and peak < SQUARE_RANGE[0]:
        raise UserError(f"{path}: scale for {name!r} is {factor:g}; it shrinks {name} to "
                        f"{peak:.3g} at most, whose squares underflow float64 to 0; expected a "
                        f"unit factor (e.g. 35.15 for V to N, 0.001 for mm to m)")
    return scaled


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
    path = Path(path)
    if not path.exists():
        raise UserError(f"{path}: file not found")
    if not path.is_file():  # a device (/dev/zero), a pipe or a folder never ends or is no record
        raise UserError(f"{path}: not a regular file; a record is a .csv, .npz or .mat file")
    size = path.stat().st_size
    if size > MAX_RECORD_BYTES:
        raise UserError(f"{path}: {size / 2 ** 30:.3g} GB, above the {MAX_RECORD_BYTES / 2 ** 30:g} "
                        f"GB a record may have (1e7 samples of t, r, y, u as CSV are ~0.8 GB)")
    raw, file_meta = _read_columns(path)
    columns = dict(columns or {})
    names = sorted(raw)  # a .mat file may hold hundreds: the line stays a line
    have = (", ".join(names[:30]) + (f", ... ({len(names) - 30} more)" if len(names) > 30 else "")
            or "none")

    def known(name, what):  # a typo would silently leave a signal out (or at its default)
        if name not in SIGNALS:
            raise UserError(f"{path}: cannot {what}: no such signal; the signals are "
                            f"{', '.join(SIGNALS)}")

    for name, key in columns.items():
        known(name, f"map {name!r} to a column")
        if key not in raw:
            raise UserError(f"{path}: missing column {key!r} (signal {name}); "
                            f"columns present: {have}")
    read_by: dict[str, str] = {}
    for name in SIGNALS:  # one column is one signal: y read as r too gives a zero error
        key = columns.get(name, name)
        if key in raw and key in read_by:
            raise UserError(f"{path}: signals {read_by[key]} and {name} would both be read from "
                            f"column {key!r}; map each signal to a column of its own")
        read_by.setdefault(key, name)
    out = {}
    for name in SIGNALS:
        key = columns.get(name, name)
        if key not in raw:
            if name in REQUIRED:
                raise UserError(f"{path}: missing column {key!r} (signal {name}); "
                                f"columns present: {have}")
            continue
        value = _numbers(raw[key], path, key)
        if value.ndim == 0:
            raise UserError(f"{path}: column {key!r} is a single number, expected a column "
                            f"of samples")
        if value.ndim > 1:
            if min(value.shape) != 1:
                raise UserError(f"{path}: column {key!r} must be a vector, got shape "
                                f"{value.shape}")
            value = value.ravel()
        out[name] = value
    for name, factor in (scale or {}).items():
        known(name, f"scale {name!r}")
        if name not in out:
            raise UserError(f"{path}: cannot scale {name!r}: no column {name!r} in the file "
                            f"(map it to one: {name}=COLUMN); columns present: {have}")
        if isinstance(factor, str):
            if factor not in raw or not isinstance(raw[factor], np.ndarray) \
                    or raw[factor].dtype.kind not in "biufc" or np.size(raw[factor]) != 1:
                raise UserError(f"{path}: scale for {name!r} names {factor!r}, which is not a "
                                f"scalar number in the file")
            factor = float(_numbers(raw[factor], path, factor).ravel()[0])
        if not (np.isfinite(factor) and factor != 0):
            raise UserError(f"{path}: scale for {name!r} is {factor:g}; expected a finite, "
                            f"non-zero factor")
        out[name] = _scaled(out[name], float(factor), path, name)
    n = len(out["t"])
    for name, value in out.items():
        if len(value) != n:
            raise UserError(f"{path}: column {columns.get(name, name)!r} has {len(value)} "
                            f"samples, t has {n}")
        bad = ~np.isfinite(value)
        if bad.any() and name in REQUIRED:
            raise UserError(f"{path}: column {columns.get(name, name)!r} holds NaN or inf "
                            f"(first at row {int(np.argmax(bad))})")
    if n < min_samples:
        raise UserError(f"{path}: record too short: {n} samples, need at least {min_samples}")
    ts = _uniform_step(out["t"], np.asarray(raw[columns.get("t", "t")]).ravel(),
                       f"{path}: column {columns.get('t', 't')!r}")
    # Orders of magnitude that SI data cannot have: catch ms time stamps and mm positions.
    if ts > MAX_TS:
        raise UserError(f"{path}: column {columns.get('t', 't')!r} steps by {ts:.6g} s, slower "
                        f"than a servo log ({1 / MAX_TS:g} Hz at least); are the time stamps "
                        f"in ms? (t must be in s)")
    if ts < MIN_TS:
        raise UserError(f"{path}: column {columns.get('t', 't')!r} steps by {ts:.6g} s, faster "
                        f"than any servo log ({1 / MIN_TS:g} Hz at most); t must be in s")
    for name in ("r", "y"):
        peak = float(np.max(np.abs(out[name])))
        if peak > MAX_POSITION_M:
            raise UserError(f"{path}: column {columns.get(name, name)!r} reaches {peak:.6g}, "
                            f"beyond {MAX_POSITION_M:g} m; positions must be in m (for a record "
                            f"in mm, scale {name} by 0.001)")
    peak = float(np.max(np.abs(out["u"])))
    if peak > MAX_FORCE_N:
        raise UserError(f"{path}: column {columns.get('u', 'u')!r} reaches {peak:.6g}, beyond "
                        f"{MAX_FORCE_N:g} N of any linear motor; u must be a force in N")
    return Run(**out, meta={**file_meta, "source": str(path)})

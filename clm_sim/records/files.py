"""Reading a record file's variables, whatever its format (CSV with a header, NPZ, MATLAB
``.mat``), and refusing in one line what is no record: a foreign or truncated file, a CSV in
another locale (';' between columns, decimal commas), a cell that is no number, an archive that
unpacks to more than a record may hold."""

from __future__ import annotations

import json
import re
import warnings
from pathlib import Path

import numpy as np

from clm_sim.errors import UserError

# The formats a record is read from (by suffix, any case): what no model or config file is.
RECORD_SUFFIXES = (".csv", ".npz", ".mat")
MAX_RECORD_BYTES = 2 ** 30  # a record file (or an .npz's arrays) larger is refused before reading
GENFROMTXT_BYTES = 50 * 2 ** 20  # CSVs with empty cells are read by genfromtxt up to this size


def read_columns(path: Path) -> tuple[dict[str, np.ndarray], dict]:
    """The file's variables (arrays as stored, checked by
    :func:`clm_sim.records.checks.numbers` when used) and its ``meta`` (a JSON object, else
    empty), read by the format its suffix names. Every failure is one ``UserError`` line."""
    suffix = path.suffix.lower()
    reader = _READERS.get(suffix)
    if reader is None:
        raise UserError(f"{path}: unknown record format {suffix!r}; expected .csv, .npz or .mat")
    try:
        return reader(path)
    except UserError:
        raise
    except FileNotFoundError:
        raise UserError(f"{path}: file not found") from None
    except Exception as exc:  # a truncated or foreign file (any error), said in one line
        raise UserError(f"{path}: cannot read as {suffix[1:].upper()} ({_first_line(exc)})") \
            from None


def _read_csv(path: Path) -> tuple[dict[str, np.ndarray], dict]:
    """A CSV's columns by the names of its header line; no ``meta``."""
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
                            f"{seen[n] + 1} and {i + 1}); give every column its own name")
        seen[n] = i
    data = _read_csv_rows(path, names)
    if data.size == 0:
        raise UserError(f"{path}: no data rows after the header")
    if data.shape[1] != len(names):
        raise UserError(f"{path}: header has {len(names)} columns, rows have "
                        f"{data.shape[1]}" + (DECIMAL_COMMAS if _commas(path, names, data)
                                              else ""))
    return {n: data[:, i] for i, n in enumerate(names)}, {}


def _read_npz(path: Path) -> tuple[dict[str, np.ndarray], dict]:
    """An NPZ archive's arrays, and its ``meta`` entry (JSON text)."""
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


def _read_mat(path: Path) -> tuple[dict[str, np.ndarray], dict]:
    """A MATLAB file's variables (not its ``__header__`` entries); no ``meta``."""
    import scipy.io
    d = scipy.io.loadmat(path)
    return {k: v for k, v in d.items() if not k.startswith("__")}, {}


_READERS = {".csv": _read_csv, ".npz": _read_npz, ".mat": _read_mat}


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

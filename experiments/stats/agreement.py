"""Whether a published results table and a fresh run agree within the cross-machine tolerance.

On one machine a config and seed give the same bits. On another CPU the numerical libraries run
other kernels (AVX-512 instead of AVX2, another BLAS build), the last bits of the fits' sums
differ, and a fit that ends in a nearly flat valley of its cost amplifies them: some seeds stop
elsewhere in the valley (measured here by running the same fits on other kernels:
``docs/reproducibility.md``). A machine difference is therefore a perturbation of the seeds' end
points, and a row may move as far as its seeds do. The tolerance of every cell of a table, plus
one unit of its last printed digit for the rounding:

* **a mean over n seeds of a tracking error** (MAE): one standard error, ``s/√n``, with ``s`` the
  larger of the two sample standard deviations: the resolution the table itself claims; for a
  row most of whose fits did not converge in either run (their end points are the iteration
  cap's, not the data's), 1.96·√2 standard errors: a machine difference draws such end points
  anew, and two independent means differ by less than that in 95 % of cases;
* **a sample standard deviation**: its own standard error, ``s/√(2(n−1))`` (normal samples);
  in a row most of whose fits did not converge, 1.96·√2 of it, for the reason above (two
  independent standard deviations);
* **a mean over seeds of a physical parameter**: its seed-to-seed spread ``s``, the larger of
  the spread printed beside it (``mean ± std``) and the fresh run's: where the data leave θ free,
  the optimizer picks it, so the table can promise no more than the spread of what it picks, and
  either run may be the one whose seeds went further down the valley (one rule both ways, as
  for the MAE). The printed spread itself is not compared: where θ is free, one seed far down
  the valley makes it, and it is the tolerance's measure, not a claim;
* **a single value** (feedback only, the LIP, θ of a row whose seeds agree): nothing more than
  the rounding: it comes from sequential code and a well-conditioned least squares whose
  machine differences are ~1e-14 relative;
* **fits converged**: one fit (a fit may stop on either side of the first-order threshold), and
  one more per fit at the edge in either run (a convergence test within its margin of its
  threshold: ``controllers.pgnn.fit_record.verdict``).
"""

from __future__ import annotations

import json
import math
import re
from dataclasses import dataclass
from pathlib import Path

from clm_sim.errors import UserError
from clm_sim.modelfile import read_json, regular_file
from clm_sim.plant import THETA_UNITS
from experiments.table import RecordRow, Row, Stat, rows_entry, table_rows

_SHORT = {"m": "mass", "fv": "viscous", "fc": "coulomb", "fk": "stiffness"}
_NUMBER = r"[-+]?(?:\d+\.?\d*|\.\d+)(?:e[-+]?\d+)?"


@dataclass(frozen=True)
class Cell:
    """A printed number and the unit of its last printed digit (``0.014`` -> 0.001)."""

    value: float
    ulp: float

    @staticmethod
    def parse(text: str) -> Cell:
        text = text.strip()
        if not re.fullmatch(_NUMBER, text, flags=re.IGNORECASE):
            raise ValueError(text)
        mantissa = re.split(r"[eE]", text)[0]
        exponent = int(re.split(r"[eE]", text)[1]) if re.search(r"[eE]", text) else 0
        decimals = len(mantissa.split(".")[1]) if "." in mantissa else 0
        return Cell(float(text), 10.0 ** (exponent - decimals))


@dataclass(frozen=True)
class Mismatch:
    """A cell outside its tolerance: row label, column, expected, fresh, allowed difference."""

    row: str
    column: str
    expected: float
    fresh: float
    allowed: float
    rule: str

    def __str__(self) -> str:
        if self.column == "row":  # a row of one table only: no numbers to subtract
            return f"{self.row}: row {self.rule}"
        if not math.isfinite(self.fresh):
            return f"{self.row} | {self.column}: expected {self.expected:.6g}, {self.rule}"
        return (f"{self.row} | {self.column}: expected {self.expected:.6g}, fresh {self.fresh:.6g} "
                f"(|diff| {abs(self.fresh - self.expected):.3g} > {self.allowed:.3g}, {self.rule})")


def parse_markdown(text: str, source: str = "table") -> list[dict[str, str]]:
    """The first results table (header starting ``| feedforward``) of a Markdown text, as one
    dict per row keyed by the header's cells."""
    lines = text.splitlines()
    try:
        start = next(i for i, line in enumerate(lines) if line.startswith("| feedforward"))
    except StopIteration:
        raise UserError(f"{source}: no results table (a line starting '| feedforward')") from None
    head = [c.strip() for c in lines[start].strip().strip("|").split("|")]
    twice = next((c for i, c in enumerate(head) if c in head[:i]), None)
    if twice is not None:  # a dict per row would keep the second and check it silently
        raise UserError(f"{source}: the column {twice!r} is given twice; which one is the "
                        f"table's?")
    rows = []
    for line in lines[start + 2:]:
        if not line.startswith("|"):
            break
        cells = [c.strip() for c in line.strip().strip("|").split("|")]
        if len(cells) != len(head):
            raise UserError(f"{source}: a table line has {len(cells)} cells, the header "
                            f"{len(head)}: {line[:80]}")
        rows.append(dict(zip(head, cells)))
    return rows


def _mean_std(text: str) -> tuple[Cell, Cell | None]:
    mean, _, std = text.partition("±")
    return Cell.parse(mean), Cell.parse(std) if std.strip() else None


def compare(expected: list[dict[str, str]], fresh: dict) -> list[Mismatch]:
    """Cells of the ``expected`` Markdown rows (:func:`parse_markdown`) that a fresh
    ``table.json`` document (its rows read by :func:`experiments.table.rows_entry`) does not
    reproduce within the tolerance (module docstring).

    A row or column missing on either side is a mismatch too (``allowed`` 0). A table that
    cannot be checked (no rows, no column this module knows, a cell that is not a number, a
    fresh value that is missing or not a number) is refused with ``UserError``."""
    if not expected:
        raise UserError("the expected table has no rows: nothing to check")
    if not any(_kind(c) for c in expected[0]):
        raise UserError(f"the expected table has no column clm-sim compares (MAE <ref> [um], "
                        f"force rms <record> <side> [N], m/fv/fc/fk, fits converged); got "
                        f"{', '.join(expected[0])}")
    for column in expected[0]:
        _check_unit(column)
    fresh_rows = [rows_entry(row, i, with_fits=False)
                  for i, row in enumerate(table_rows(fresh, "table.json"))]
    rows = {row.label: row for row in fresh_rows}
    out: list[Mismatch] = []
    for exp in expected:
        label = exp.get("feedforward", "")
        if label not in rows:
            out.append(Mismatch(label, "row", math.nan, math.nan, 0.0, "not in the fresh table"))
            continue
        row = rows[label]
        n = row.n_seeds
        seeds = exp.get("seeds", "")
        if not seeds.isdecimal():
            raise UserError(f"row {label!r}: seeds: expected an integer, got {seeds!r}")
        if int(seeds) != n:
            out.append(Mismatch(label, "seeds", int(seeds), n, 0.0, "same seed count"))
            continue
        undetermined = _undetermined(row, n) or _page_undetermined(exp, n)
        for column, text in exp.items():
            try:
                out += _check_cell(label, column, text, row, n, undetermined)
            except (ValueError, KeyError, TypeError, IndexError, AttributeError) as exc:
                what = f"cannot read {text!r}" if isinstance(exc, ValueError) else \
                    f"the fresh row has no number for it ({type(exc).__name__}: {exc})"
                raise UserError(f"row {label!r}, column {column!r}: {what}") from None
    labels = {e.get("feedforward") for e in expected}
    missing = [r.label for r in fresh_rows if r.label not in labels]
    out += [Mismatch(label, "row", math.nan, math.nan, 0.0, "not in the expected table")
            for label in missing]
    return out


def _kind(column: str) -> str | None:
    """What a column of a results table holds (None: a column this module does not check)."""
    words = column.split()
    if column.startswith("MAE ") and len(words) >= 2:
        return "mae"
    if column.startswith("force rms ") and len(words) >= 4 and words[3] in ("inside", "outside"):
        return "force_rms"
    if words and words[0] in _SHORT:
        return "theta"
    if column == "fits converged":
        return "fits"
    return None


def _unit(column: str) -> str | None:
    """The unit a results table prints its column in (:func:`experiments.table.results_table`,
    ``experiments.records.fit``): what the fresh table's numbers mean in that column."""
    kind = _kind(column)
    if kind == "mae":
        return "µm"
    if kind == "force_rms":
        return "N"
    if kind == "theta":
        return THETA_UNITS[_SHORT[column.split()[0]]]
    return None


def _check_unit(column: str) -> None:
    """Refuse a compared column whose header gives another unit than the fresh table's (a page
    in nm or g would be read as µm or kg), or none."""
    unit = _unit(column)
    if unit is None:
        return
    given = re.search(r"\[([^\]]*)\]", column)
    text = given.group(1).strip() if given else None
    if text == unit or (unit == "µm" and text in ("um", "μm")):  # ASCII; the Greek mu
        return
    raise UserError(f"column {column!r}: unit {'[' + text + ']' if given else 'missing'}; "
                    f"clm-sim compares it in [{unit}] (write the header and its numbers in "
                    f"{unit})")


def skipped_columns(expected: list[dict[str, str]]) -> list[str]:
    """The columns of the expected table that are not compared (besides the row's name and
    seeds)."""
    head = list(expected[0]) if expected else []
    return [c for c in head if _kind(c) is None and c not in ("feedforward", "seeds")]


def _number(value, what: str) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
        raise TypeError(f"{what} is {json.dumps(value)}")
    return float(value)


def _check_spread(label: str, column: str, text: str, fresh: Stat, n: int, undetermined: bool,
                  factor: float, key: str = "") -> list[Mismatch]:
    """A ``mean ± std`` cell against the fresh :class:`Stat` (times ``factor``; ``key``:
    its place in table.json, for messages): the mean within one standard error over seeds, the
    std within its own standard error."""
    mean, std = _mean_std(text.split("(median")[0])
    f_mean = _number(fresh.mean, f"{key}mean") * factor
    f_std = _number(fresh.std, f"{key}std") * factor
    s = max(std.value if std else 0.0, f_std)
    se = s / math.sqrt(n) if n > 1 else 0.0
    if undetermined:
        found = [_within(label, column, mean, f_mean, UNDETERMINED_FACTOR * se,
                         "fits that did not converge: two independent means, 95 %")]
    else:
        found = [_within(label, column, mean, f_mean, se,
                         "one standard error of the mean over seeds")]
    if std is not None and n > 1:
        se_std = s / math.sqrt(2 * (n - 1))
        found.append(_within(label, column + " std", std, f_std, UNDETERMINED_FACTOR * se_std,
                             "fits that did not converge: two independent standard deviations, "
                             "95 %") if undetermined else
                     _within(label, column + " std", std, f_std, se_std,
                             "the standard error of a standard deviation"))
    return [m for m in found if m]


def _check_cell(label: str, column: str, text: str, row: Row | RecordRow, n: int,
                undetermined: bool) -> list[Mismatch]:
    if text in ("–", "-", "") or column in ("feedforward", "seeds"):
        return []
    kind = _kind(column)
    if kind == "force_rms":  # force rms <record> <side> [N]: a data: table
        _, _, record, side = column.split()[:4]
        fresh = row.force_rms[record][side]
        if fresh is None:
            return [Mismatch(label, column, Cell.parse(text.split()[0]).value, math.nan, 0.0,
                             "no such sample in the fresh run")]
        return _check_spread(label, column, text, fresh, n, undetermined, 1.0)
    if kind == "mae":
        ref = column.split()[1]
        return _check_spread(label, column, text, row.mae[ref], n, undetermined, 1e6,
                             f"mae.{ref}.")
    if kind == "theta":
        name = _SHORT[column.split()[0]]
        per_seed = row.theta_phy_per_seed or []
        values = [_number(t[name], f"theta_phy_per_seed.{name}") for t in per_seed]
        mean, std = _mean_std(text)
        spread = max(_sample_std(values), std.value if std else 0.0)
        m = _within(label, column, mean,
                    _number(row.theta_phy[name], f"theta_phy.{name}"), spread,
                    "the seed-to-seed spread of the parameter")
        return [m] if m else []
    if kind == "fits":
        done = int(text.split("/")[0])
        edge = re.search(r"\((\d+) at the edge\)", text)
        slack = 1 + max(int(edge.group(1)) if edge else 0, row.at_edge or 0)
        if row.converged is not None and abs(row.converged - done) > slack:
            return [Mismatch(label, column, done, row.converged, float(slack),
                             "one fit and those at the edge")]
        return []
    return []


UNDETERMINED_FACTOR = 1.96 * math.sqrt(2.0)
"""Where most fits of a row stopped at their iteration cap (a cost without a minimizer, as the
paper's lambda = 0 cost), the data do not fix their end points and a machine difference draws
them anew: two independent means over n seeds differ by less than 1.96·√2 standard errors in 95 %
of cases."""


def _page_undetermined(exp: dict[str, str], n: int) -> bool:
    """Whether the page's own row says most of its fits did not converge (``k/n`` in its
    ``fits converged`` column): a row is read as undetermined when either run says so, so that
    the verdict does not depend on which run is the page."""
    done = exp.get("fits converged", "").split("/")[0].strip()
    return done.isdecimal() and n > 1 and int(done) < n / 2


def _undetermined(row: Row | RecordRow, n: int) -> bool:
    """Whether most of a PGNN row's fits did not converge (``converged`` below half)."""
    return row.converged is not None and n > 1 and row.converged < n / 2


def _sample_std(values: list[float]) -> float:
    if len(values) < 2:
        return 0.0
    mean = sum(values) / len(values)
    return math.sqrt(sum((v - mean) ** 2 for v in values) / (len(values) - 1))


def _within(label: str, column: str, expected: Cell, fresh: float, allowed: float,
            rule: str) -> Mismatch | None:
    """A mismatch when ``fresh`` differs from the printed ``expected`` by more than ``allowed``
    plus one unit of the printed last digit (the rounding)."""
    limit = allowed + expected.ulp
    if abs(fresh - expected.value) <= limit * (1 + 1e-12):
        return None
    return Mismatch(label, column, expected.value, fresh, limit,
                    rule + " + one unit of the last printed digit")


def compare_files(expected: Path, fresh: Path) -> list[Mismatch]:
    """:func:`compare` of a Markdown file's first results table with a ``table.json``."""
    def unreadable(path, exc) -> UserError:
        return UserError(f"{path}: cannot read it ({str(exc).removeprefix(f'{path}: ')})")

    try:
        text = regular_file(expected, "Markdown file").read_text(encoding="utf-8")
    except (UserError, OSError, UnicodeDecodeError) as exc:
        raise unreadable(expected, exc) from None
    try:
        doc = read_json(fresh, "clm-sim table.json")  # strict: no NaN, no deep nesting
    except UserError as exc:
        raise unreadable(fresh, exc) from None
    table_rows(doc, fresh)
    try:
        return compare(parse_markdown(text, str(expected)), doc)
    except UserError as exc:
        raise UserError(f"{fresh} against {expected}: {exc}") from None



def verdict(expected: Path, fresh: Path) -> tuple[list[str], int]:
    """What ``clm-sim compare`` prints and its exit code: 0 where ``fresh`` reproduces the
    table in ``expected``, else 1 with one line per cell outside the tolerance; the columns it
    did not compare are listed either way."""
    found = compare_files(Path(expected), Path(fresh))
    mismatches = [str(m) for m in found]
    skipped = skipped_columns(parse_markdown(Path(expected).read_text(encoding="utf-8")))
    note = [f"not compared (columns clm-sim does not check): {', '.join(skipped)}"] \
        if skipped else []
    if mismatches:
        rows = sum(m.column == "row" for m in found)  # a row of one table only
        cells = len(mismatches) - rows
        counts = ([f"{cells} cell(s) outside the cross-machine tolerance "
                   f"(docs/reproducibility.md)"] if cells else []) + \
                 ([f"{rows} row(s) in one table only (a table of another config?)"] if rows else [])
        return mismatches + note + ["; ".join(counts)], 1
    return note + [f"{fresh} reproduces the table in {expected} within the cross-machine "
                   f"tolerance" + (" in the columns it compares" if skipped else "")], 0

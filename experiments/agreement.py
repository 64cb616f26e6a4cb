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
  row most of whose fits did not converge (their end points are the iteration cap's, not the
  data's), 1.96·√2 standard errors: a machine difference draws such end points anew, and two
  independent means differ by less than that in 95 % of cases;
* **a sample standard deviation**: its own standard error, ``s/√(2(n−1))`` (normal samples);
* **a mean over seeds of a physical parameter**: its seed-to-seed spread ``s`` (from the fresh
  run's per-seed values): where the data leave θ free, the optimizer picks it, so the table can
  promise no more than the spread of what it picks;
* **a single value** (feedback only, the LIP, θ of a row whose seeds agree): nothing more than
  the rounding: it comes from sequential code and a well-conditioned least squares whose
  machine differences are ~1e-14 relative;
* **fits converged**: one fit (a fit may stop on either side of the first-order threshold).
"""

from __future__ import annotations

import json
import math
import re
from dataclasses import dataclass
from pathlib import Path

from clm_sim.errors import UserError

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
    ``table.json`` document does not reproduce within the tolerance (module docstring).

    A row or column missing on either side is a mismatch too (``allowed`` 0)."""
    rows = {row["label"]: row for row in fresh["rows"]}
    out: list[Mismatch] = []
    for exp in expected:
        label = exp["feedforward"]
        if label not in rows:
            out.append(Mismatch(label, "row", math.nan, math.nan, 0.0, "missing in the fresh run"))
            continue
        row = rows[label]
        n = int(row["n_seeds"])
        if int(exp["seeds"]) != n:
            out.append(Mismatch(label, "seeds", int(exp["seeds"]), n, 0.0, "same seed count"))
            continue
        for column, text in exp.items():
            out += _check_cell(label, column, text, row, n)
    missing = [r["label"] for r in fresh["rows"] if r["label"] not in {e["feedforward"] for e in expected}]
    out += [Mismatch(label, "row", math.nan, math.nan, 0.0, "not in the expected table")
            for label in missing]
    return out


def _check_cell(label: str, column: str, text: str, row: dict, n: int) -> list[Mismatch]:
    if text in ("–", "-", "") or column in ("feedforward", "seeds"):
        return []
    if column.startswith("MAE "):
        ref = column.split()[1]
        mean, std = _mean_std(text)
        fresh = row["mae"][ref]
        f_mean, f_std = fresh["mean"] * 1e6, fresh["std"] * 1e6
        s = max(std.value if std else 0.0, f_std)
        se = s / math.sqrt(n) if n > 1 else 0.0
        if _undetermined(row, n):
            found = [_within(label, column, mean, f_mean, UNDETERMINED_FACTOR * se,
                             "fits that did not converge: two independent means, 95 %")]
        else:
            found = [_within(label, column, mean, f_mean, se,
                             "one standard error of the mean over seeds")]
        if std is not None and n > 1:
            found.append(_within(label, column + " std", std, f_std, s / math.sqrt(2 * (n - 1)),
                                 "the standard error of a standard deviation"))
        return [m for m in found if m]
    if column.split()[0] in _SHORT:
        name = _SHORT[column.split()[0]]
        per_seed = row.get("theta_phy_per_seed") or []
        values = [t[name] for t in per_seed]
        spread = _sample_std(values)
        m = _within(label, column, Cell.parse(text), row["theta_phy"][name], spread,
                    "the seed-to-seed spread of the parameter")
        return [m] if m else []
    if column == "fits converged":
        done = int(text.split("/")[0])
        if "converged" in row and abs(row["converged"] - done) > 1:
            return [Mismatch(label, column, done, row["converged"], 1.0, "one fit")]
        return []
    return []


UNDETERMINED_FACTOR = 1.96 * math.sqrt(2.0)
"""Where most fits of a row stopped at their iteration cap (a cost without a minimizer, as the
paper's lambda = 0 cost), the data do not fix their end points and a machine difference draws
them anew: two independent means over n seeds differ by less than 1.96·√2 standard errors in 95 %
of cases."""


def _undetermined(row: dict, n: int) -> bool:
    """Whether most of a PGNN row's fits did not converge (``converged`` below half)."""
    return "converged" in row and n > 1 and row["converged"] < n / 2


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
    try:
        text = Path(expected).read_text(encoding="utf-8")
        doc = json.loads(Path(fresh).read_text(encoding="utf-8"))
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise UserError(f"{getattr(exc, 'filename', None) or fresh}: cannot read it ({exc})") from None
    if not isinstance(doc, dict) or not isinstance(doc.get("rows"), list):
        raise UserError(f"{fresh}: not a clm-sim table.json (no 'rows' list)")
    return compare(parse_markdown(text, str(expected)), doc)



def verdict(expected: Path, fresh: Path) -> tuple[list[str], int]:
    """What ``clm-sim compare`` prints and its exit code: 0 where ``fresh`` reproduces the
    table in ``expected``, else 1 with one line per cell outside the tolerance."""
    lines = [str(m) for m in compare_files(Path(expected), Path(fresh))]
    if lines:
        return lines + [f"{len(lines)} cell(s) outside the cross-machine tolerance "
                        f"(docs/reproducibility.md)"], 1
    return [f"{fresh} reproduces the table in {expected} within the cross-machine "
            f"tolerance"], 0

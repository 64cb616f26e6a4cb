"""What a command prints when it is done: what the user came for, read back from the files it
wrote (nothing computed twice), and where the rest is.

``clm-sim run`` prints the results table, the fits and the paired comparisons in a few lines
(per metric and varied setting: how many hold after Holm's adjustment, and by how much), then
where ``table.md`` (every comparison with its rows, the fits, θ_phy's paths) and the figures
are. ``clm-sim study`` prints its report up to its findings, then where the full report is.
Progress stays on stderr; the files are not touched here.
"""

from __future__ import annotations

import json
from pathlib import Path

from experiments.report.table_json import read as read_table
from experiments.report.table_md import fmt_diff
from experiments.stats.comparisons import Comparison, ComparisonFamily


def _where(c: Comparison) -> str:
    """The quantity a comparison measures, in a few words."""
    if c.on_records:  # a run on measured records: force rms per record and side
        return f"force rms, {c.record} {c.side}"
    name = {"mae": "MAE", "theta_drift": "θ drift", "data_cost": "data cost"}.get(c.metric,
                                                                                 c.metric)
    return name + (f" on {c.reference}" if c.reference else "")


def _diff(c: Comparison, x: float) -> str:
    return f"{x:+.3f} N" if c.on_records else fmt_diff(c.metric, x)


def comparison_lines(pairs: ComparisonFamily) -> list[str]:
    """The paired comparisons in one line per (quantity, varied setting): how many hold after
    Holm (``starred``), with the difference and its interval where one does, the range of the
    differences where several do. MAE always; θ drift and data cost where one holds, the rest
    counted in one line."""
    if not pairs:
        return []
    groups: dict[tuple[str, str], list[Comparison]] = {}
    for c in pairs:
        groups.setdefault((_where(c), c.varies), []).append(c)
    held = sum(c.starred for c in pairs)
    lines = [f"Paired comparisons (a − b, same seeds; one setting apart or vs the LIP): "
             f"{len(pairs)}, {held} hold after Holm:"]
    quiet = 0
    for (where, varies), cs in groups.items():
        stars = [c for c in cs if c.starred]
        if not stars and cs[0].metric != "mae":  # MAE always; the rest where held
            quiet += len(cs)
            continue
        text = f"  {where}, varies {varies}: {len(stars)} of {len(cs)} hold"
        if len(stars) == 1:
            c = stars[0]
            ci = f" [{_diff(c, c.ci95[0])}, {_diff(c, c.ci95[1])}]" if c.ci95 else ""
            text += f" ({_diff(c, c.diff)}{ci})"
        elif stars:
            diffs = sorted(c.diff for c in stars)
            text += f" ({_diff(stars[0], diffs[0])} to {_diff(stars[0], diffs[-1])})"
        lines.append(text)
    if quiet:
        lines.append(f"  and {quiet} comparisons of θ drift and data cost, none holding")
    return lines


def run_summary(out: Path) -> str:
    """What ``clm-sim run`` prints: the table of ``out/table.md``, the fits and the comparisons
    of ``out/table.json`` in a few lines, and where the full report and the figures are."""
    out = Path(out)
    table = (out / "table.md").read_text().split("\n\n", 1)[0].rstrip("\n")
    rows, pairs = read_table(json.loads((out / "table.json").read_text()), out / "table.json")
    lines = [table, ""]
    fits = [f for row in rows for f in row.fits or ()]
    if fits:
        done = sum(f.converged for f in fits)
        lines.append(f"Fits: {done} of {len(fits)} converged"
                     + (" (⚠ marks the rows; table.md names each stop)." if done < len(fits)
                        else "."))
    lines += comparison_lines(pairs)
    lines.append(_files_line(out, "table.md", "every comparison with its rows, the fits"))
    return "\n".join(lines) + "\n"


def report_summary(out: Path, name: str = "report.md") -> str:
    """What ``clm-sim study`` prints: its report up to the end of its findings (the section named
    for them, where the report has one; else everything before its figures), then where the
    full report and the figures are."""
    out = Path(out)
    lines = (out / name).read_text().splitlines()
    heads = [i for i, line in enumerate(lines) if line.startswith("## ")]
    found = [k for k, i in enumerate(heads) if "finding" in lines[i].lower()
             or "generated from this run" in lines[i]]
    figures = [i for i in heads if lines[i].lower().startswith("## figures")]
    if found:
        cut = heads[found[0] + 1] if found[0] + 1 < len(heads) else len(lines)
    else:
        cut = figures[0] if figures else len(lines)
    head = "\n".join(lines[:cut]).rstrip("\n")
    return head + "\n\n" + _files_line(out, name, "every table and section") + "\n"


def _files_line(out: Path, report: str, holds: str) -> str:
    """Where the full report is, and the figures where the command drew any."""
    figures = out / "figures"
    drawn = figures.is_dir() and any(figures.iterdir())
    return f"Full report: {out / report} ({holds})" + (f"\nFigures: {figures}/" if drawn else "")

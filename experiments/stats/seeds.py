"""A sweep's rows summarized over its swept seeds: merged rows (:func:`over_seeds`) and the MAE
series a figure draws against a swept key (:func:`series`).

A sweep's row is a :class:`experiments.table.Row` whose ``extra`` holds the swept keys, its task
key and its feedforward position ``row``.
"""

from __future__ import annotations

import re
from dataclasses import dataclass

import numpy as np

from clm_sim.plant import THETA_NAMES
from experiments.table import Row, Stat

POSITION = "row"  # a sweep row's feedforward position in its task's config


@dataclass(frozen=True)
class SeedStat:
    """One quantity over the swept seeds: the mean of the per-seed means, their sample std
    (with one seed, that seed's own std over its training seeds) and the seed count."""

    mean: float
    std: float
    n: int

    @classmethod
    def of(cls, stats: list[Stat]) -> SeedStat:
        means = np.array([s.mean for s in stats])
        spread = float(means.std(ddof=1)) if len(means) > 1 else float(stats[0].std)
        return cls(float(means.mean()), spread, len(means))


def over_seeds(rows: list[Row], swept: list[str]) -> list[Row]:
    """Rows of a sweep that differ only in the swept ``seed`` merged into one row each, in the
    order they first appear: MAE mean ± sample std over the seeds, theta_phy averaged (each
    seed's in ``theta_phy_per_seed``, so that the table prints its spread over the seeds),
    ``n_seeds`` the number of seeds merged. Rows are matched by feedforward position and every
    other swept key that can change them: a row no key of its own changes (the LIP beside a
    PGNN whose lambda is swept) is one row, those keys ``None``."""
    others = [k for k in swept if k != "seed"]
    groups: dict[tuple, list[Row]] = {}
    seen = set()
    for row in rows:
        pos = row.value(POSITION)
        own = tuple(row.value(k) if _applies(k, pos) else None for k in others)
        seed = row.value("seed")
        if (pos, own, seed) in seen:
            continue  # the same row of the same seed, copied across another row's keys
        seen.add((pos, own, seed))
        groups.setdefault((pos, own), []).append(row)
    out = []
    for (pos, own), members in groups.items():
        first = members[0]
        thetas = [m.theta_phy for m in members if m.theta_phy]
        mae = {}
        for ref in first.mae:
            s = SeedStat.of([m.mae[ref] for m in members])
            mae[ref] = Stat(s.mean, s.std)
        out.append(Row(
            first.kind, first.training, first.lam, first.hidden, len(members), first.label,
            {k: float(np.mean([t[k] for t in thetas])) for k in THETA_NAMES} if thetas else None,
            thetas or None, mae=mae, extra={**dict(zip(others, own)), POSITION: pos}))
    return out


def _series_labels(rows: list[Row]) -> dict[int, str]:
    """A label per feedforward position that does not change along the sweep."""
    by_pos: dict[int, set] = {}
    for row in rows:
        by_pos.setdefault(row.value(POSITION), set()).add(row.label)
    labels = {}
    for pos, names in by_pos.items():
        if len(names) == 1:
            labels[pos] = next(iter(names))
        else:
            row = next(r for r in rows if r.value(POSITION) == pos)
            labels[pos] = {"none": "feedback only", "lip": "LIP"}.get(
                row.kind, f"PGNN {row.training}")
    return labels


def _applies(key: str, position: int) -> bool:
    """Whether swept ``key`` can change the row at feedforward ``position`` (a key of another
    feedforward, ``feedforwards[j]...``, cannot)."""
    m = re.match(r"feedforwards\[(\d+)\]", key)
    return m is None or int(m.group(1)) == position


def key_value(key: str, value) -> str:
    text = "–" if value is None else f"{value:g}" if isinstance(value, float) else str(value)
    return f"{key.split('.')[-1]}={text}"


def series(rows: list[Row], swept: list[str], x: str, describe=key_value) -> dict:
    """``{(label, ref): {x_value: (mean, spread, n)}}``: MAE (m) per series and x, with the
    spread over the swept seeds (:class:`SeedStat`). Other swept keys split the series (named
    ``label, describe(key, value), ...``). A row that ``x`` cannot change (the LIP when a
    PGNN's lambda is swept) is one flat series: the same statistics at every x; copies of it
    from grid points that differ only in another feedforward's keys count once."""
    labels = _series_labels(rows)
    xs = list(dict.fromkeys(row.value(x) for row in rows))
    groups: dict = {}
    seen = set()
    for row in rows:
        pos = row.value(POSITION)
        applies = [k for k in swept if _applies(k, pos)]
        ident = (pos, tuple(row.value(k) for k in applies))
        if ident in seen:
            continue
        seen.add(ident)
        name = labels[pos] + "".join(f", {describe(k, row.value(k))}"
                                     for k in applies if k not in (x, "seed"))
        for ref, stat in row.mae.items():
            by_x = groups.setdefault((name, ref), {})
            for xv in ([row.value(x)] if x in applies else xs):
                by_x.setdefault(xv, []).append(stat)
    out = {}
    for key, by_x in groups.items():
        out[key] = {}
        for xv, stats in by_x.items():
            s = SeedStat.of(stats)
            out[key][xv] = (s.mean, s.std, s.n)
    return out

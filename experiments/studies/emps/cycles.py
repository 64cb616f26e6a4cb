"""The EMPS benchmark's folds: the training record's cycles, each left out once.

The training record's reference repeats one program (EMPS: four times). The record is cut at
the reference's reversals at the low end of the stroke (found on the reference, never on the
measured output); each candidate is made on the other cycles joined (each seam a reversal at one
position, where the reference is continuous) and simulated open loop on the left-out cycle.
"""

from __future__ import annotations

import numpy as np

from clm_sim.errors import UserError
from clm_sim.run import SIGNALS, Run


def cycle_edges(r: np.ndarray, cycles: int) -> tuple[int, ...]:
    """Sample indices ``(0, b1, ..., n)`` cutting a reference ``r`` (m) into ``cycles`` parts at
    its reversals at the low end of its stroke (a minimum in the lowest tenth of the range)."""
    r = np.asarray(r, dtype=float)
    d = np.diff(r)
    moving = np.flatnonzero(np.abs(d) > 1e-9 * max(float(np.ptp(r)), 1e-12))
    s = np.sign(d[moving])
    up = moving[1:][(s[:-1] < 0) & (s[1:] > 0)]  # first rising step after a falling one
    low = r.min() + 0.1 * np.ptp(r)
    turns = [int(i) for i in up if r[i] <= low]
    if len(turns) != cycles - 1:
        raise UserError(f"benchmark.cycles: {cycles} cycles need {cycles - 1} reversals at the "
                        f"low end of the training record's reference; it has {len(turns)}")
    return (0, *turns, len(r))


def joined(parts: list[Run]) -> Run:
    """The runs one after another as one run (time restarted at the first part's start with
    the first part's sample time; meta of the first part)."""
    ts = parts[0].ts
    signals = {k: np.concatenate([getattr(p, k) for p in parts]) for k in SIGNALS if k != "t"}
    n = len(signals["y"])
    return Run(t=parts[0].t[0] + ts * np.arange(n), **signals, meta=parts[0].meta)


def left_out(run: Run, edges: tuple[int, ...], k: int) -> tuple[Run, Run]:
    """``(estimation, held out)``: every cycle but the ``k``-th joined, and the ``k``-th."""
    parts = [run.slice(a, b) for j, (a, b) in enumerate(zip(edges[:-1], edges[1:])) if j != k]
    return joined(parts), run.slice(edges[k], edges[k + 1])

"""Rule C of the EMPS benchmark's selection: leave one cycle out, then the one-standard-error rule.

The training record's reference repeats one program (EMPS: four times). The record is cut at
the reference's reversals at the low end of the stroke (found on the reference, never on the
measured output); each candidate is made on the other cycles joined (each seam a reversal at one
position, where the reference is continuous) and simulated open loop on the left-out cycle. The
choice (:func:`one_se_choice`): the candidate with the fewest fitted parameters whose mean RMSE
over the cycles is within one standard error of the lowest mean (Hastie, Tibshirani and Friedman,
*The Elements of Statistical Learning*, 2nd ed., sec. 7.10); equal counts go to the lower mean.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from clm_sim.errors import UserError
from clm_sim.plant import Plant
from clm_sim.record import SIGNALS, Run

# Numbers each effect type takes from the data when the diagnosis names it (its coefficients and
# the searched nonlinear parameter: a Stribeck velocity, a cogging period, a pre-sliding length).
_FITTED = {"stribeck": 2, "cogging": 3, "presliding": 2, "force_ripple": 3}


def fitted_parameters(plant: Plant) -> int:
    """How many numbers of ``plant`` were taken from data: mass, viscous and Coulomb friction,
    the stiffness where it is not 0, one constant force (all offsets are one), one per
    direction-asymmetric friction pair that is not 0, and per other effect its coefficients and
    searched nonlinear parameter."""
    n = 3 + (plant.stiffness != 0.0)
    n += any(e.type == "force_offset" for e in plant.effects)
    for e in plant.effects:
        if e.type == "friction_asymmetry":
            n += (e.coulomb_pos != 0.0 or e.coulomb_neg != 0.0)
            n += (e.viscous_pos != 0.0 or e.viscous_neg != 0.0)
        elif e.type != "force_offset":
            n += _FITTED.get(e.type, len(e.parameters()))
    return int(n)


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


@dataclass(frozen=True)
class CycleScores:
    """A candidate's open-loop RMSE (m) on each left-out cycle, its fitted parameters, and
    (``remade``) each fold's model described (its parameters and its fit's note)."""

    rmse_m: tuple[float, ...]
    parameters: int
    remade: tuple[str, ...] = ()

    @property
    def mean(self) -> float:
        return float(np.mean(self.rmse_m))

    @property
    def se(self) -> float:
        """Standard deviation of the cycles' RMSEs over the square root of their count (m)."""
        return float(np.std(self.rmse_m, ddof=1) / np.sqrt(len(self.rmse_m)))


def one_se_choice(scores: dict[str, CycleScores]) -> str:
    """The name with the fewest parameters whose mean is within one standard error (of the
    lowest-mean candidate) of the lowest mean; equal counts go to the lower mean."""
    best = min(scores, key=lambda k: scores[k].mean)
    bar = scores[best].mean + scores[best].se
    within = [k for k, s in scores.items() if s.mean <= bar]
    return min(within, key=lambda k: (scores[k].parameters, scores[k].mean))

"""The encoder origin of a second record: register it to the estimation record's frame.

An incremental encoder is zeroed wherever the axis is homed, at every power-up. A force tied to
the angle of a rotating part or to a magnet track (``cogging``, ``force_ripple``) then sits at
another measured position in each experiment, while the smooth forces hardly move. On EMPS the
2.501 mm periodic force is in both records with the same amplitude, 0.66 mm apart. The extended
model is therefore carried to another record with one nuisance parameter, the origin shift
``delta`` (m): that record's positions are read as ``y + delta``. Like the initial state of a
simulation (the EMPS benchmark protocol spends the first 20 test samples on it), ``delta`` is
estimated on the first part of the validation record only, and the gain is measured on the rest.
"""

from __future__ import annotations

import numpy as np
import scipy.optimize

from clm_sim.features import edge_force
from clm_sim.plant import Plant
from clm_sim.run import Run
from experiments.diagnosis.families import periodic_effect_types
from experiments.diagnosis.outcome import OriginGain
from experiments.diagnosis.residual import DiagnosisSettings, Residual


def dominant_period(plant: Plant, run: Run) -> float | None:
    """Period (m) of the position-periodic effect of ``plant`` with the largest force RMS on
    ``run``; None when the plant has none (then the origin does not matter)."""
    periodic = [e for e in plant.effects if isinstance(e, periodic_effect_types())]
    if not periodic:
        return None
    y, u = np.asarray(run.y, dtype=float), edge_force(run.u)
    return max(periodic, key=lambda e: float(np.std(e.force(y, 0.0, u)))).period


def origin_scan(run: Run, plant: Plant, settings: DiagnosisSettings,
                period: float) -> tuple[float, np.ndarray, np.ndarray]:
    """``(delta, shifts, rms)``: the origin shift ``delta`` (m, within half a period (m) of 0)
    that minimizes the residual RMS (N) of ``plant`` on ``run.moved_origin(delta)``, and the
    scanned grid.

    A grid of 64 steps over one period, then a bounded scalar search around the best point (to
    1e-4 of the period). Shifts by whole periods of the dominant effect are not told apart: the
    smallest is returned (a homing error is a fraction of a millimetre, not centimetres).
    """
    def cost(delta: float) -> float:
        return Residual(run.moved_origin(delta), plant, settings).rms()

    grid = np.linspace(-0.5, 0.5, 65) * period
    costs = np.array([cost(d) for d in grid])
    k = int(np.argmin(costs))
    step = float(grid[1] - grid[0])
    best = scipy.optimize.minimize_scalar(cost, bounds=(grid[k] - step, grid[k] + step),
                                          method="bounded", options={"xatol": 1e-4 * period})
    delta = float(best.x) if best.fun <= costs[k] else float(grid[k])
    return delta, grid, costs


def registered_gain(val: Run, before: Plant, after: Plant, settings: DiagnosisSettings,
                    resimulate=None) -> tuple[OriginGain, tuple] | None:
    """The out-of-sample gain on a separate validation record with its origin registered:
    ``delta`` from the first ``settings.registration_fraction`` of ``val`` (the extended model
    ``after``), the residuals of both models on the rest. None when ``after`` has no periodic
    effect. ``resimulate(plant, run) -> e`` (m), if given, re-simulates the loop over the whole
    moved record and the mismatch is taken on the rest. Returns the numbers and the scan
    ``(delta, shifts, rms)`` of :func:`origin_scan` for the report's figure."""
    period = dominant_period(after, val)
    if period is None:
        return None
    cut = int(round(settings.registration_fraction * len(val)))
    reg, rest = val.slice(0, cut), val.slice(cut)
    scan = origin_scan(reg, after, settings, period)
    delta = scan[0]
    moved = rest.moved_origin(delta)
    out = {"shift_m": delta, "period_m": period,
           "registered_on": f"first {100 * settings.registration_fraction:.0f} % of the "
                            f"validation record ({cut} samples)",
           "samples": len(rest),
           "residual_rms_before": Residual(moved, before, settings).rms(),
           "residual_rms_after_fixed_origin": Residual(rest, after, settings).rms(),
           "residual_rms_after": Residual(moved, after, settings).rms()}
    out["residual_rms_reduction"] = 1.0 - out["residual_rms_after"] / \
        max(out["residual_rms_before"], 1e-300)
    if resimulate is not None:
        whole = val.moved_origin(delta)
        e_m = val.e[cut:]
        for key, plant, run in (("before", before, whole), ("after", after, whole),
                                ("after_fixed_origin", after, val)):
            e = resimulate(plant, run)[cut:]
            out[f"resim_mismatch_rms_{key}"] = float(np.sqrt(np.mean((e - e_m) ** 2)))
    return OriginGain(**out), scan

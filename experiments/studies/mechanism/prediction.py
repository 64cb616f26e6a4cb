"""What the cubic-continuation reading predicts for finding (iii) on a plant, before any fit.

The reading (docs/results/lambda0.md, section 4): with theta free to cancel any slope, lambda = 0's
network carries the position force it fitted inside the training range as a polynomial (a near-
linear tanh unit's Taylor remainder), which continues beyond the range; held at theta_LIP
(lambda = 0.01) the network builds that force from units that saturate beyond the range, so
beyond it the model continues the LIP's line. Written as two feedforwards that need no fit:

* ``continued cubic`` (the reading's lambda = 0): the exact motor command of the reference's
  motion, with the plant's static (position) force beyond the range replaced by its value at the
  range's edge plus the increment of the least-squares cubic fitted to it inside the range;
* ``continued line`` (the reading's lambda = 0.01): the same with the increment of the
  least-squares line fitted inside the range (the LIP's stiffness, read from the plant).

Replayed in the closed loop on the outside reference, their MAE difference (line minus cubic, as
the study prints lambda = 0.01 minus lambda = 0) is the predicted amount; their static force
error beyond the range is the predicted force error of each row. Everything is computed from the
plant's force law; nothing here fits a PGNN or reads a result.

``python -m experiments.studies.mechanism.prediction CONFIG`` prints it for each case of a
mechanism config.
"""

from __future__ import annotations

import sys
from dataclasses import replace

import numpy as np

from clm_sim.effects import total_force
from clm_sim.features import TrainingRange, held_force


class _Feedforward:
    """A fixed feedforward signal for one reference, in the shape ``Testbed.replay`` takes."""

    def __init__(self, r: np.ndarray, force: np.ndarray):
        self.r, self.force = r, force

    def feedforward(self, r, ts):
        assert np.array_equal(r, self.r)
        return held_force(self.force)


def static_force(effects, y: np.ndarray) -> np.ndarray:
    """The case's position force at rest (N) at positions ``y`` (m): what a dwell holds."""
    zeros = np.zeros_like(y)
    return total_force(effects, y, zeros, zeros)


def continued(effects, y: np.ndarray, limit: float, degree: int, grid: int = 401) -> np.ndarray:
    """The static force, beyond ``|y| > limit`` replaced by its edge value plus the increment of
    the least-squares polynomial of ``degree`` fitted to it on a uniform grid inside."""
    inside = np.linspace(-limit, limit, grid)
    poly = np.polynomial.Polynomial.fit(inside, static_force(effects, inside), degree)
    out = static_force(effects, y)
    for side in (-1.0, 1.0):
        edge = side * limit
        where = side * y > limit
        out[where] = (static_force(effects, np.array([edge]))[0]
                      + poly(y[where]) - poly(edge))
    return out


def predict(config, effects, *, inside: str = "r1", outside: str = "r2",
            grid_points: int = 69) -> dict:
    """The reading's prediction on the plant of ``config`` with ``effects``: per surrogate row
    the static force error beyond the range (rms, N, on the study's grid) and the MAE on
    ``outside`` (m); ``mae_diff_m``: continued line minus continued cubic."""
    from experiments.testbed import Testbed

    config = replace(config, plant=replace(config.plant, effects=tuple(effects)))
    tb = Testbed(config)
    ts = config.ts
    limit = TrainingRange.of(config.features, tb.reference(inside), ts).position_m
    reach = float(np.max(np.abs(tb.reference(outside))))
    y = np.linspace(-reach, reach, grid_points)
    beyond = np.abs(y) > limit
    truth = static_force(effects, y)
    sig = config.references[outside].sample(ts)
    need = tb.machine.motor_command(sig.r, sig.v, sig.a)
    rows = {}
    for name, degree in (("continued cubic", 3), ("continued line", 1)):
        sur = continued(effects, y, limit, degree)
        along = need - static_force(effects, sig.r) + continued(effects, sig.r, limit, degree)
        rows[name] = {
            "error_beyond_rms_n": float(np.sqrt(np.mean((sur - truth)[beyond] ** 2))),
            "mae_outside_m": tb.replay(_Feedforward(sig.r, along), sig.r).mae}
    exact = tb.replay(_Feedforward(sig.r, need), sig.r).mae
    return {"position_limit_m": limit, "reach_m": reach, "rows": rows, "exact_mae_m": exact,
            "truth_beyond_rms_n": float(np.sqrt(np.mean(truth[beyond] ** 2))),
            "mae_diff_m": rows["continued line"]["mae_outside_m"]
            - rows["continued cubic"]["mae_outside_m"]}


def main(argv=None) -> int:
    from experiments.studies.mechanism.settings import load_mechanism

    argv = sys.argv[1:] if argv is None else argv
    config, settings = load_mechanism(argv[0])
    for case, effects in settings.cases.items():
        p = predict(config, effects, inside=settings.inside, outside=settings.outside,
                    grid_points=settings.grid_points)
        rows = p["rows"]
        line, cub = (rows[k]["mae_outside_m"] * 1e6 for k in ("continued line", "continued cubic"))
        print(f"{case}: MAE {settings.outside}, continued line - continued cubic: "
              f"{p['mae_diff_m'] * 1e6:+.3f} um (line {line:.3f}, cubic {cub:.3f}, exact "
              f"{p['exact_mae_m'] * 1e6:.3f}); static force error beyond the range, rms: cubic "
              f"{rows['continued cubic']['error_beyond_rms_n']:.3f} N, line "
              f"{rows['continued line']['error_beyond_rms_n']:.3f} N (true force there "
              f"{p['truth_beyond_rms_n']:.3f} N rms)")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

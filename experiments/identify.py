"""``clm-sim identify``: the LIP feedforward of a measured record, and its ``lip.json``.

    record -> guards (can it carry a LIP at all?) -> LIP (least squares, the feature map's
    filter) -> plausibility of the result -> printed parameters, lip.json

The command line only parses its options and prints :class:`Identified`'s lines.
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass, replace
from pathlib import Path

from clm_sim.errors import UserError
from clm_sim.features import FeatureMap
from clm_sim.outdir import atomic_write, write_error
from controllers.lip import LIPFeedforward
from experiments.record_guards import fit_warnings, refuse_unidentifiable
from experiments.suspicions import record_warnings
from experiments.table import THETA_UNITS


@dataclass(frozen=True)
class Identified:
    """A LIP identified from a record: the model, the record's size and rate, the warnings
    (one line each; the result may be suspect) and the source file."""

    lip: LIPFeedforward
    samples: int
    ts: float
    warnings: tuple[str, ...]
    source: str

    def lines(self) -> list[str]:
        """The parameters with their standard errors and the residual, as printed."""
        lip = self.lip
        out = [f"{name:10s} {value:12.6g} {THETA_UNITS[name]:6s} (std {lip.std_[name]:.2g})"
               for name, value in lip.theta_.items()]
        out.append(f"residual rms {lip.residual_rms_:.4g} N over {self.samples} samples at "
                   f"{1 / self.ts:g} Hz")
        return out

    def write(self, out: Path) -> Path:
        """``out/lip.json`` (atomically): the model and its source."""
        path = Path(out) / "lip.json"
        try:
            atomic_write(path, json.dumps({**self.lip.to_json(), "source": self.source},
                                          indent=1, allow_nan=False))
        except OSError as exc:
            raise write_error(out, exc) from None
        return path


def features_for(cutoff: float | None) -> FeatureMap:
    """The feature map of ``--regression-lowpass-hz``: None the default, <= 0 no filter."""
    if cutoff is None:
        return FeatureMap()
    return FeatureMap(regression_lowpass_hz=None if cutoff <= 0 else cutoff)


def identify(run, *, source: str, regression_lowpass_hz: float | None = None) -> Identified:
    """The LIP of the record ``run`` (read from ``source``, named in every message).

    Raises ``UserError`` (one line) where the record cannot carry a LIP (no motion, no force,
    too few samples) or the fit gives non-finite numbers; a cut-off outside the record's band
    names ``--regression-lowpass-hz``."""
    refuse_unidentifiable(run, source)
    cutoff = regression_lowpass_hz
    try:
        features = features_for(cutoff)
        lip = LIPFeedforward(features=features).fit(y=run.y, u=run.u, ts=run.ts)
    except UserError as exc:  # name the file and the option
        raise UserError(f"{source}: {exc}" + (" (--regression-lowpass-hz)"
                                              if "lowpass" in str(exc) else "")) from None
    values = {**lip.theta_, **lip.std_}
    bad = [name for name, value in values.items() if not math.isfinite(value)]
    if bad or not math.isfinite(lip.residual_rms_):
        raise UserError(f"{source}: the fit gives non-finite parameters "
                        f"({', '.join(sorted(set(bad))) or 'residual'}); the record's values are "
                        f"too large or degenerate for a least-squares fit")
    def refit(y, cutoff):
        try:
            band = replace(features, regression_lowpass_hz=cutoff)
            return LIPFeedforward(features=band).fit(y=y, u=run.u, ts=run.ts).theta_["mass"]
        except UserError:
            return float("nan")

    warnings = record_warnings(run, lip) + fit_warnings(
        run, features, lip.theta_, lip.std_, option="--regression-lowpass-hz", refit=refit)
    return Identified(lip, len(run), run.ts, tuple(warnings), str(source))

"""``clm-sim identify``: a LIP from a record, by the product's defaults or a published protocol.

    record (+ validation record) -> IDIM-LS fit (controllers.idim) -> lip.json, printed summary,
    cross-test force error on the validation record (the same processing)
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass
from pathlib import Path

from clm_sim.errors import UserError
from clm_sim.outdir import atomic_write, write_error
from clm_sim.record import Run
from controllers.idim import CrossTest, IDIMFit, IDIMProtocol, cross_test, fit
from experiments.table import THETA_UNITS

UNITS = {**THETA_UNITS, "offset": "N"}


@dataclass(frozen=True)
class Identified:
    """What ``identify`` found: the ``fit``, the record it came from, the cross-test on the
    validation record (None without one) and the data warnings (one line each)."""

    fit: IDIMFit
    run: Run
    source: str
    cross: CrossTest | None = None
    validation: str | None = None
    warnings: tuple[str, ...] = ()

    def summary(self) -> str:
        """The coefficients, the residual and the cross-test, one per line."""
        f = self.fit
        lines = [f"{name:10s} {value:12.6g} {UNITS[name]:6s} (std {f.std[name]:.2g})"
                 for name, value in f.coefficients.items()]
        if not f.protocol.stiffness:
            lines.append(f"{'stiffness':10s} {0.0:12.6g} {UNITS['stiffness']:6s} (fixed)")
        lines.append(f"residual rms {f.residual_rms_n:.4g} N, relative error "
                     f"{100 * f.relative_error:.3g} % over {f.samples} fitted samples "
                     f"({len(self.run)} at {1 / self.run.ts:g} Hz)")
        if self.cross is not None:
            lines.append(f"cross-test on {self.validation}: residual rms "
                         f"{self.cross.residual_rms_n:.4g} N, relative error "
                         f"{100 * self.cross.relative_error:.3g} % over {self.cross.samples} "
                         f"samples (the same processing)")
        return "\n".join(lines)


def identify(run: Run, protocol: IDIMProtocol, *, source: str,
             validation: Run | None = None, validation_source: str | None = None
             ) -> Identified:
    """Fit ``run`` by ``protocol``; cross-test on ``validation`` (same sample time) if given.
    Errors name ``source`` (or ``validation_source``)."""
    from experiments.suspicions import record_warnings

    try:
        result = fit(y=run.y, u=run.u, ts=run.ts, protocol=protocol)
    except UserError as exc:
        raise UserError(f"{source}: {exc}") from None
    values = {**result.coefficients, **result.std}
    bad = [name for name, value in values.items() if not math.isfinite(value)]
    if bad or not math.isfinite(result.residual_rms_n):
        raise UserError(f"{source}: the fit gives non-finite parameters "
                        f"({', '.join(sorted(set(bad))) or 'residual'}); the record's values are "
                        f"too large or degenerate for a least-squares fit")
    cross = None
    if validation is not None:
        if abs(validation.ts / run.ts - 1) > 1e-3:
            raise UserError(f"{validation_source}: sampled at {validation.ts:g} s, the record at "
                            f"{run.ts:g} s; the cross-test needs the same rate")
        try:
            cross = cross_test(result, y=validation.y, u=validation.u, ts=validation.ts)
        except UserError as exc:
            raise UserError(f"{validation_source}: {exc}") from None
    return Identified(result, run, source, cross, validation_source,
                      tuple(record_warnings(run, result.model)))


def write(result: Identified, out: Path) -> Path:
    """Write ``out/lip.json`` (the model, its source and the protocol); returns its path."""
    info = {**result.fit.model.to_json(), "source": result.source,
            "identification": {**result.fit.protocol.as_dict(),
                               "relative_error": result.fit.relative_error,
                               "fitted_samples": result.fit.samples}}
    if result.cross is not None:
        info["cross_test"] = {"record": result.validation,
                              "relative_error": result.cross.relative_error,
                              "residual_rms_n": result.cross.residual_rms_n,
                              "samples": result.cross.samples}
    try:
        atomic_write(out / "lip.json", json.dumps(info, indent=1, allow_nan=False))
    except OSError as exc:
        raise write_error(out, exc) from None
    return out / "lip.json"

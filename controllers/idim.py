"""A LIP identified by a published IDIM-LS protocol (inverse dynamics, least squares).

Janot, Gautier and Brunot's EMPS procedure (the benchmark's ``Script_IDIM_LS.m``) is, in this
module's terms::

    IDIMProtocol(position_lowpass_hz=100, filter_order=4, zero_phase=True,
                 differentiation="central_twice", regression_lowpass_hz=None,
                 decimation=10, offset=True, edge_samples=49, force_at="sample")

the position filtered by a 4th-order Butterworth at 100 Hz forwards and backwards; the velocity
its central difference and the acceleration the central difference of the velocity; the columns
``[a, v, sign v, 1]`` and the force decimated by 10 (``scipy.signal.decimate``: an 8th-order
Chebyshev type I low-pass at 0.8 of the new Nyquist frequency, forwards and backwards, then every
10th sample, as MATLAB's ``decimate``); least squares with the standard deviations of
``sigma^2 (X'X)^-1`` and the relative error ``||F - X theta|| / ||F||``.

The product's own LIP (:class:`controllers.lip.LIPFeedforward`) differs in four choices, each an
option here: no position filter (the sign of the velocity must match the Coulomb force that was
applied, ``clm_sim.features``), the second difference for the acceleration, a zero-phase
Butterworth as the parallel filter instead of decimation, and the force averaged onto the sample
instant from the two held inputs around it (``force_at="edge"``). The fitted model is a
``LIPFeedforward`` (an offset column becomes a ``force_offset`` effect); its ``predict`` uses the
product's feature map with the protocol's position filter (zero-phase, second difference): the
function identified and the function replayed agree up to the differentiation stencil and the
decimation filter, both far above the motion's band.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass

import numpy as np
import scipy.signal

from clm_sim.effects.position import ForceOffset
from clm_sim.errors import UserError
from clm_sim.features import FeatureMap, check_realisable, edge_force
from clm_sim.plant import THETA_NAMES
from clm_sim.rigid_body import rigid_body_columns
from controllers.lip import LIPFeedforward

DIFFERENTIATIONS = ("second_difference", "central_twice")
FORCE_AT = ("edge", "sample")


@dataclass(frozen=True)
class IDIMProtocol:
    """How the columns and the force of an IDIM-LS fit are made from a record.

    position_lowpass_hz: Butterworth cut-off (Hz) applied to the position before differencing
    (None: raw). filter_order: order of that filter and of the parallel filter. zero_phase:
    filter forwards and backwards (else forwards only, causal). differentiation:
    ``"second_difference"`` (``a[k] = (y[k+1] - 2 y[k] + y[k-1]) / ts^2``) or ``"central_twice"``
    (the central difference of the central-difference velocity). regression_lowpass_hz: the
    parallel Butterworth on every column and the force (None: none). decimation: keep every n-th
    sample after an anti-aliasing filter on every column and the force (1: none). offset: a
    constant-force column (a ``force_offset``). edge_samples: samples dropped at each end before
    decimating. force_at: ``"edge"`` (the two held inputs around the sample averaged) or
    ``"sample"`` (``u[k]`` as recorded). Stiffness (a position column) is part of the product's
    LIP; ``stiffness=False`` leaves it out, as the EMPS model does.
    """

    position_lowpass_hz: float | None = None
    filter_order: int = 4
    zero_phase: bool = True
    differentiation: str = "second_difference"
    regression_lowpass_hz: float | None = 250.0
    decimation: int = 1
    offset: bool = False
    stiffness: bool = True
    edge_samples: int = 200
    force_at: str = "edge"

    def __post_init__(self):
        for key in ("position_lowpass_hz", "regression_lowpass_hz"):
            value = getattr(self, key)
            if value is not None and not (isinstance(value, (int, float)) and value > 0):
                raise UserError(f"identify: {key} must be > 0 Hz or none, got {value!r}")
        if not (isinstance(self.filter_order, int) and 1 <= self.filter_order <= 12):
            raise UserError(f"identify: filter order must be an integer in 1..12, "
                            f"got {self.filter_order!r}")
        if self.differentiation not in DIFFERENTIATIONS:
            raise UserError(f"identify: differentiation must be one of "
                            f"{', '.join(DIFFERENTIATIONS)}, got {self.differentiation!r}")
        if self.force_at not in FORCE_AT:
            raise UserError(f"identify: force_at must be one of {', '.join(FORCE_AT)}, "
                            f"got {self.force_at!r}")
        if not (isinstance(self.decimation, int) and 1 <= self.decimation <= 1000):
            raise UserError(f"identify: decimation must be an integer in 1..1000, "
                            f"got {self.decimation!r}")
        if not (isinstance(self.edge_samples, int) and self.edge_samples >= 0):
            raise UserError(f"identify: edge_samples must be an integer >= 0, "
                            f"got {self.edge_samples!r}")

    def as_dict(self) -> dict:
        return dataclasses.asdict(self)

    def is_product_lip(self) -> bool:
        """Whether this is exactly what :class:`LIPFeedforward` with a ``FeatureMap`` does."""
        return (self.position_lowpass_hz is None and self.differentiation == "second_difference"
                and self.decimation == 1 and self.force_at == "edge" and self.stiffness
                and self.zero_phase and self.edge_samples >= 1)

    def feature_map(self) -> FeatureMap:
        """The product's feature map closest to this protocol: what the fitted model's
        ``predict`` uses (zero-phase filters, second difference)."""
        return FeatureMap(regression_lowpass_hz=self.regression_lowpass_hz,
                          position_lowpass_hz=self.position_lowpass_hz,
                          lowpass_order=self.filter_order,
                          edge_samples=max(self.edge_samples, 1))

    def _lowpass(self, x: np.ndarray, ts: float, cutoff: float, key: str) -> np.ndarray:
        nyquist = 0.5 / ts
        if cutoff >= nyquist:
            raise UserError(f"identify: {key} {cutoff:g} Hz is at or above the Nyquist "
                            f"frequency {nyquist:g} Hz of this record")
        check_realisable(cutoff, nyquist, f"identify: {key}")
        sos = scipy.signal.butter(self.filter_order, cutoff, fs=1.0 / ts, output="sos")
        if self.zero_phase:
            return scipy.signal.sosfiltfilt(sos, x, axis=0)
        return scipy.signal.sosfilt(sos, x, axis=0)

    def motion(self, y: np.ndarray, ts: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """``(y, v, a)`` (m, m/s, m/s^2) at the sample instants, as the protocol makes them."""
        y = np.asarray(y, dtype=np.float64)
        if self.position_lowpass_hz is not None:
            y = self._lowpass(y, ts, self.position_lowpass_hz, "position_lowpass_hz")
        v = _central(y, ts)
        if self.differentiation == "central_twice":
            a = _central(v, ts)
        else:
            a = np.empty_like(y)
            a[1:-1] = (y[2:] - 2.0 * y[1:-1] + y[:-2]) / (ts * ts)
            a[0], a[-1] = a[1], a[-2]
        return y, v, a

    def columns(self, y: np.ndarray, u: np.ndarray, ts: float) -> tuple[np.ndarray, np.ndarray,
                                                                       list[str]]:
        """``(X, F, names)``: the regression's columns and force after filtering, edge removal
        and decimation, and the coefficient names (``THETA_NAMES`` order, then ``offset``)."""
        yf, v, a = self.motion(y, ts)
        cols = dict(zip(THETA_NAMES, rigid_body_columns(a, v, np.sign(v), yf)))
        if not self.stiffness:
            del cols["stiffness"]
        if self.offset:
            cols["offset"] = np.ones_like(yf)
        x = np.column_stack(list(cols.values()))
        f = edge_force(u) if self.force_at == "edge" else np.asarray(u, dtype=np.float64)
        if self.regression_lowpass_hz is not None:
            x = self._lowpass(x, ts, self.regression_lowpass_hz, "regression_lowpass_hz")
            f = self._lowpass(f, ts, self.regression_lowpass_hz, "regression_lowpass_hz")
        n = len(f)
        e = self.edge_samples
        if n - 2 * e < 30 * self.decimation + 10:
            raise UserError(f"identify: a record of {n} samples is too short for "
                            f"{e} edge samples and decimation {self.decimation}")
        x, f = x[e:n - e], f[e:n - e]
        if self.decimation > 1:
            # MATLAB's decimate: Chebyshev I of order 8 at 0.8 of the new Nyquist, zero-phase.
            x = scipy.signal.decimate(x, self.decimation, ftype="iir", axis=0, zero_phase=True)
            f = scipy.signal.decimate(f, self.decimation, ftype="iir", zero_phase=True)
        return x, f, list(cols)


def _central(x: np.ndarray, ts: float) -> np.ndarray:
    out = np.empty_like(x)
    out[1:-1] = (x[2:] - x[:-2]) / (2.0 * ts)
    out[0], out[-1] = out[1], out[-2]
    return out


@dataclass(frozen=True)
class IDIMFit:
    """An IDIM-LS fit: ``model`` (a fitted ``LIPFeedforward``), the coefficients and their
    standard deviations by name (SI units), the relative error ``||e||/||F||`` and the residual
    RMS (N) of the fitted samples, their count and the protocol."""

    model: LIPFeedforward
    coefficients: dict
    std: dict
    relative_error: float
    residual_rms_n: float
    samples: int
    protocol: IDIMProtocol

    def __str__(self) -> str:
        return "\n".join(f"{k:10s} {v:12.6g} (std {self.std[k]:.2g})"
                         for k, v in self.coefficients.items())


def fit(*, y: np.ndarray, u: np.ndarray, ts: float, protocol: IDIMProtocol) -> IDIMFit:
    """Identify ``[mass, viscous, coulomb, (stiffness), (offset)]`` from positions ``y`` (m) and
    forces ``u`` (N) sampled at ``ts`` (s) by ``protocol``. Where the protocol is the product's
    own LIP (:meth:`IDIMProtocol.is_product_lip`), the fit is ``LIPFeedforward.fit`` itself
    (an offset column as its ``force_offset`` effect)."""
    x, f, names = protocol.columns(y, u, ts)
    effects = (ForceOffset(),) if protocol.offset else ()
    if protocol.is_product_lip():
        try:
            lip = LIPFeedforward(features=protocol.feature_map(), effects=effects).fit(
                y=y, u=u, ts=ts)
        except UserError as exc:
            raise UserError(f"identify: {str(exc).removeprefix('lip: ')}") from None
        coef = np.array([lip.coef_[n] for n in names])
        std = {n: lip.std_[n] for n in names}
    else:
        scale = np.linalg.norm(x, axis=0)
        if np.any(scale == 0) or np.linalg.matrix_rank(x / scale) < x.shape[1]:
            raise UserError("identify: the record does not excite all parameters (a column is "
                            "zero or collinear); it needs motion in both directions")
        coef = np.linalg.lstsq(x / scale, f, rcond=None)[0] / scale
        resid = f - x @ coef
        cov = np.linalg.pinv(x.T @ x) * (resid @ resid / max(len(f) - len(coef), 1))
        std = {n: float(s) for n, s in zip(names, np.sqrt(np.clip(np.diag(cov), 0, None)))}
        coefficients = dict(zip(names, map(float, coef)))
        theta = {k: coefficients.get(k, 0.0) for k in THETA_NAMES}
        fitted = tuple(e.from_coefficients(coefficients) for e in effects)
        lip = LIPFeedforward.fitted(theta=theta, effects=fitted, features=protocol.feature_map(),
                                    ts=ts)
        lip.coef_ = coefficients
        lip.std_ = {**{k: 0.0 for k in THETA_NAMES}, **std}  # a left-out column: fixed at 0
        lip.residual_rms_ = float(np.sqrt(np.mean(resid ** 2)))
    resid = f - x @ coef
    return IDIMFit(lip, dict(zip(names, map(float, coef))), std,
                   float(np.linalg.norm(resid) / np.linalg.norm(f)),
                   float(np.sqrt(np.mean(resid ** 2))), len(f), protocol)


@dataclass(frozen=True)
class CrossTest:
    """A fitted model's force error on another record processed by the same protocol:
    ``||F - X theta|| / ||F||`` and the RMS (N) over ``samples`` samples."""

    relative_error: float
    residual_rms_n: float
    samples: int


def cross_test(result: IDIMFit, *, y: np.ndarray, u: np.ndarray, ts: float) -> CrossTest:
    """The fitted coefficients applied to another record's columns (the same protocol)."""
    x, f, names = result.protocol.columns(y, u, ts)
    resid = f - x @ np.array([result.coefficients[n] for n in names])
    return CrossTest(float(np.linalg.norm(resid) / np.linalg.norm(f)),
                     float(np.sqrt(np.mean(resid ** 2))), len(f))

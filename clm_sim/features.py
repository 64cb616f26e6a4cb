"""Motion features from sampled positions, aligned with the zero-order-held input.

The controller holds ``u[k]`` over ``[t_k, t_k+1)`` while the encoder reads ``y`` at the sample
edges. For a mass the exact sampled relation is
``y[k+1] - 2*y[k] + y[k-1] = ts**2/m * (u[k-1] + u[k])/2``, so the central second difference at
``t_k`` pairs with the *average of the two inputs held around it*, not with ``u[k]``; the dither
makes ``u`` white and the difference matters. Hence:

* ``motion(y)``: position, velocity and acceleration at the sample instants (central differences);
* ``edge_force(u)``: ``(u[k-1] + u[k])/2``, the force that goes with ``motion`` at ``t_k``;
* ``held_force(p)``: the inverse map, ``(p[k] + p[k+1])/2``, the input to hold over a sample to
  produce forces ``p`` predicted at the sample instants (how a feedforward is applied).

Encoder quantization makes second differences noisy (a 0.1 um count gives 7 m/s**2 rms at 10 kHz),
which would bias least squares (errors in variables). A linear-in-the-parameters fit therefore
passes every regressor column *and* the force through one zero-phase low-pass
(``regression_lowpass_hz``, the "parallel filter" of IDIM-LS): since ``filt(u) = sum theta_i *
filt(phi_i)`` holds exactly for a linear filter, the fit stays consistent while the noise far above
the cut-off is removed. Filtering the position *before* differencing would not do: the sign of the
velocity flips with the dither at standstill and reversals, and a smoothed velocity's sign no
longer matches the Coulomb force that was applied. ``position_lowpass_hz`` exists for inputs of
nonlinear models (networks) that cannot be filtered after the fact; it is off by default.
Everything is float64; any cast to float32 happens later, in a network.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass
from typing import ClassVar

import numpy as np

from clm_sim.errors import UserError
from clm_sim.rigid_body import rigid_body_columns

LIP_COLUMNS = ("acceleration", "velocity", "sign_velocity", "position")


@dataclass(frozen=True)
class FeatureMap:
    """Preprocessing shared by identification, replay and diagnosis.

    Positions are differenced in float64 (central differences) into velocity and
    acceleration; the columns of a linear fit and the force are low-passed alike, so the
    filter changes the noise, not the model.

    Parameters
    ----------
    regression_lowpass_hz : float or None
        Cut-off (Hz) of the zero-phase Butterworth applied to regressor columns and force in
        linear fits (``None``: no filter); below the record's Nyquist frequency.
    position_lowpass_hz : float or None
        Zero-phase low-pass of the position before differencing (``None``: raw).
    lowpass_order : int
        Order of both filters, 1 to 12.
    edge_samples : int
        Samples dropped at each end of a record for fitting (filter transients), >= 1.

    Raises
    ------
    UserError
        A cut-off that is not positive (at construction) or at or above the Nyquist frequency
        of a record (when used), an order or an edge out of range.

    Examples
    --------
    >>> import numpy as np
    >>> from clm_sim import FeatureMap
    >>> features = FeatureMap(regression_lowpass_hz=100.0)
    >>> t = np.arange(10_000) * 1e-4
    >>> y, v, a = features.motion(0.05 * t**2, ts=1e-4)  # y = 0.05 t^2 m: a = 0.1 m/s^2
    >>> round(float(np.median(a)), 6)
    0.1
    >>> features.fit_slice(len(t))
    slice(200, 9800, None)
    """

    regression_lowpass_hz: float | None = 250.0
    position_lowpass_hz: float | None = None
    lowpass_order: int = 4
    edge_samples: int = 200

    def __post_init__(self):
        for key in ("regression_lowpass_hz", "position_lowpass_hz"):
            value = getattr(self, key)
            if value is not None and not value > 0:
                raise UserError(f"features: {key} must be > 0 Hz or null, got {value}")
        if not (isinstance(self.lowpass_order, int) and 1 <= self.lowpass_order <= 12):
            raise UserError(f"features: lowpass_order must be an integer in 1..12, "
                            f"got {self.lowpass_order!r}")
        if not (isinstance(self.edge_samples, int) and self.edge_samples >= 1):
            raise UserError(f"features: edge_samples must be an integer >= 1, "
                            f"got {self.edge_samples!r}")

    def _lowpass(self, x: np.ndarray, ts: float, cutoff: float | None, key: str) -> np.ndarray:
        x = np.asarray(x, dtype=np.float64)
        if cutoff is None:
            return x
        nyquist = 0.5 / ts
        if cutoff >= nyquist:
            raise UserError(f"features: {key} {cutoff:g} Hz is at or above the Nyquist "
                            f"frequency {nyquist:g} Hz of this record")
        check_realisable(cutoff, nyquist, f"features: {key}")
        # Here, not at the top: scipy.signal (with scipy.stats) is a second of imports that a
        # PGNN fit worker, which only unpickles a FeatureMap, never needs.
        import scipy.signal

        sos = scipy.signal.butter(self.lowpass_order, cutoff, fs=1.0 / ts, output="sos")
        return scipy.signal.sosfiltfilt(sos, x, axis=0)

    def regression_filter(self, x: np.ndarray, ts: float) -> np.ndarray:
        """The parallel filter of linear fits, along axis 0 (columns of a regressor matrix)."""
        return self._lowpass(x, ts, self.regression_lowpass_hz, "regression_lowpass_hz")

    def motion(self, y: np.ndarray, ts: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """``(y, v, a)`` at the sample instants from positions ``y`` (m), sample time ``ts`` (s)."""
        return motion(self._lowpass(y, ts, self.position_lowpass_hz, "position_lowpass_hz"), ts)

    def fit_slice(self, n: int) -> slice:
        """Samples used for fitting in a record of ``n`` samples."""
        if n <= 2 * self.edge_samples + 10:
            raise UserError(f"features: record of {n} samples is too short for "
                            f"edge_samples={self.edge_samples}")
        return slice(self.edge_samples, n - self.edge_samples)


@dataclass(frozen=True)
class TrainingRange:
    """The motion a training reference covers, as a feature map sees it: the largest |position|
    (m), |velocity| (m/s) and |acceleration| (m/s²). A sample of another reference lies *beyond*
    the range where any of the three exceeds it by more than ``MARGIN`` (1 %: two references'
    sampled extremes of the same move differ in their last digits). The one definition of
    "beyond the training range" for tables, studies and figures."""

    position_m: float
    velocity_m_s: float
    acceleration_m_s2: float
    MARGIN: ClassVar[float] = 1.01

    @classmethod
    def of(cls, features: FeatureMap, r: np.ndarray, ts: float) -> TrainingRange:
        """The range of reference ``r`` (m) sampled at ``ts`` (s)."""
        return cls(*(float(np.max(np.abs(x))) for x in features.motion(r, ts)))

    def beyond(self, features: FeatureMap, r: np.ndarray, ts: float) -> np.ndarray:
        """Boolean mask of the samples of ``r`` (m) beyond this range."""
        y, v, a = features.motion(r, ts)
        m = self.MARGIN
        return ((np.abs(y) > m * self.position_m) | (np.abs(v) > m * self.velocity_m_s)
                | (np.abs(a) > m * self.acceleration_m_s2))

    def as_dict(self) -> dict[str, float]:
        return asdict(self)


# A low-pass cut-off below this fraction of the Nyquist frequency has poles that float64 cannot
# tell from 1 (scipy's filter then fails, or passes nothing but the mean); 1e-6 of 5 kHz is 5 mHz.
MIN_CUTOFF_FRACTION = 1e-6


def check_realisable(cutoff: float, nyquist: float, key: str) -> None:
    """Refuse (``UserError`` naming ``key``) a cut-off (Hz) too low to be a digital filter at
    a Nyquist frequency ``nyquist`` (Hz): see :data:`MIN_CUTOFF_FRACTION`."""
    if cutoff < MIN_CUTOFF_FRACTION * nyquist:
        raise UserError(f"{key} {cutoff:g} Hz is below {MIN_CUTOFF_FRACTION:g} of the Nyquist "
                        f"frequency {nyquist:g} Hz: no digital filter has such a cut-off; is "
                        f"it in Hz?")


def motion(y: np.ndarray, ts: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Central differences at the sample instants; ends repeat their neighbours."""
    y = np.asarray(y, dtype=np.float64)
    v = np.empty_like(y)
    a = np.empty_like(y)
    v[1:-1] = (y[2:] - y[:-2]) / (2.0 * ts)
    a[1:-1] = (y[2:] - 2.0 * y[1:-1] + y[:-2]) / (ts * ts)
    v[0], v[-1] = v[1], v[-2]
    a[0], a[-1] = a[1], a[-2]
    return y, v, a


def edge_force(u: np.ndarray) -> np.ndarray:
    """``(u[k-1] + u[k])/2``: the held inputs averaged onto the sample instant ``t_k``."""
    u = np.asarray(u, dtype=np.float64)
    out = np.empty_like(u)
    out[1:] = 0.5 * (u[1:] + u[:-1])
    out[0] = u[0]
    return out


def held_force(p: np.ndarray) -> np.ndarray:
    """``(p[k] + p[k+1])/2``: the input to hold over sample k for forces ``p`` at the instants."""
    p = np.asarray(p, dtype=np.float64)
    out = np.empty_like(p)
    out[:-1] = 0.5 * (p[:-1] + p[1:])
    out[-1] = p[-1]
    return out


def lip_regressors(y: np.ndarray, v: np.ndarray, a: np.ndarray) -> np.ndarray:
    """The LIP feature matrix ``[a, v, sign(v), y]`` (columns as ``LIP_COLUMNS``), shape (N, 4):
    the columns of :func:`clm_sim.rigid_body.rigid_body_columns`."""
    return np.column_stack(rigid_body_columns(a, v, np.sign(v), y))

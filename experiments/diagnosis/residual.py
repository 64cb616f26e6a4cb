"""The force-domain residual: measured force minus the model's inverse dynamics, ready for fits.

``residual = edge_force(u) - plant.inverse_force(y, v, a)`` at the sample instants (N, inverse-model
sign: a positive residual is force the motor supplied that the model did not expect).

Every fit in the diagnosis is a linear least-squares fit of this residual on regressor columns,
with columns and residual passed through one zero-phase low-pass (the parallel filter of
:class:`clm_sim.features.FeatureMap`, consistent under encoder quantization), then decimated to
the filter's bandwidth.

Low speed: the model's Coulomb friction acts in the direction of motion *within* the sample
interval ``[t_k-1, t_k+1]`` that the central differences and ``edge_force`` describe. Near a
reversal, at standstill and at a few counts per sample the sampled velocity's sign does not tell
that direction (with dither it flips at random), and a stuck stage holds any force inside its
breakaway band. A sample is therefore kept only where the measured position path tells the
direction: monotone over ``y[k-2..k+2]`` (every one of the four steps at least one count
the same way), and where the velocity cannot reach zero within the sample at the acceleration
the held forces give through the model (a stage that stops for part of a sample, as under dither
at a few counts per sample, holds less than its sliding friction there). This keeps slow
monotone motion (down to one count per sample) and the samples soon after a reversal, where
pre-sliding friction lives, and drops the turning samples, standstill, dither jitter and
stick-slip. Dropped samples are zeroed in the residual *and* in every column before the filter, which keeps the parallel-filter
relation exact (``0 = sum theta_i * 0``); fits then use the samples whose filter window is mostly
(>= 90 %) made of kept samples.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import scipy.ndimage
import scipy.signal

from clm_sim.errors import UserError
from clm_sim.features import FeatureMap, edge_force
from clm_sim.plant import Plant
from clm_sim.run import Run


@dataclass(frozen=True)
class DiagnosisSettings:
    """Settings of the diagnosis: its filter and its significance rule (docs/diagnosis.md).

    Parameters
    ----------
    regression_lowpass_hz : float
        Cut-off (Hz; capped at 0.2/ts) of the parallel filter, the setting of the same name
        as in a config's ``features:`` and ``clm-sim identify``; 100 Hz rather than the
        identification's 250 Hz: the narrower band keeps the encoder's quantization floor low
        and still passes the 2.5 mm periodic force of the EMPS at its speed.
    folds : int
        Contiguous blocks of the blocked cross-validation.
    min_gain : float
        Held-out MSE reduction (fraction of the current held-out MSE) a candidate must bring.
    min_explained : float
        The same reduction as a fraction of the held-out MSE of the model's own residual
        (once the large causes are removed, the remaining residual is the noise and
        quantization floor, where ``min_gain`` alone would name model bias; 2e-4 lies between
        the artifacts seen on emulated records, <= 1e-5, and the weakest real effect in the
        tests, 5e-4).
    p_value : float
        F-test level on the estimation data (effective sample count = filter bandwidth x
        duration).
    min_folds : int
        Folds in which the held-out MSE must drop.
    max_findings : int
        At most this many causes.
    holdout_fraction : float
        Final part of the record kept for the out-of-sample gain when no validation record is
        given.
    min_force_fraction : float
        The force a cause explains (RMS of the held-out MSE drop, N) must be at least this
        fraction of the RMS of the measured force: with a right model the residual is the
        noise and discretization floor (1.7 mN on a 1 nm, 10 kHz foreign record, where 20 % of
        it looked like pre-sliding), and a cause below a thousandth of the force is not worth
        a name.
    registration_fraction : float
        First part of a separate validation record on which its encoder origin is registered
        when the extended model has a periodic effect; the gain is measured on the rest.

    Raises
    ------
    UserError
        A ``regression_lowpass_hz`` that is not a positive finite number.

    Examples
    --------
    >>> from clm_sim import DiagnosisSettings
    >>> strict = DiagnosisSettings(p_value=1e-6, max_findings=2)
    >>> strict.min_gain, strict.holdout_fraction
    (0.02, 0.25)
    >>> DiagnosisSettings(regression_lowpass_hz=0)
    Traceback (most recent call last):
    ...
    clm_sim.errors.UserError: regression_lowpass_hz: the diagnosis needs a cut-off > 0 Hz, got 0
    """

    regression_lowpass_hz: float = 100.0
    folds: int = 5
    min_gain: float = 0.02
    min_explained: float = 2e-4
    p_value: float = 1e-3
    min_folds: int = 4
    max_findings: int = 6
    holdout_fraction: float = 0.25
    min_force_fraction: float = 1e-3
    registration_fraction: float = 0.25

    def __post_init__(self):
        if not (isinstance(self.regression_lowpass_hz, (int, float))
                and 0 < self.regression_lowpass_hz < float("inf")):
            raise UserError(f"regression_lowpass_hz: the diagnosis needs a cut-off > 0 Hz, got "
                            f"{self.regression_lowpass_hz!r}")


def encoder_quantum(y: np.ndarray) -> float:
    """The encoder step (m): the largest step of which every position change between samples is
    a whole multiple, among the smallest change seen and its fractions 1/2 .. 1/12 (a record that
    never moves by one count, e.g. no dither and no crawl, still has 2- and 3-count steps); the
    smallest change when the positions are on no such grid (a processed record); 0 if none."""
    d = np.abs(np.diff(np.asarray(y, dtype=float)))
    scale = max(float(np.max(np.abs(y))), 1e-12)
    d = np.unique(d[d > 1e-9 * scale])
    if not d.size:
        return 0.0
    for k in range(1, 13):
        ratio = d * k / d[0]
        if np.all(np.abs(ratio - np.round(ratio)) < 1e-3):
            return float(d[0] / k)
    return float(d[0])


def quantization_floor(quantum: float, ts: float, cutoff: float, mass: float, viscous: float,
                       order: int = 4) -> float:
    """RMS (N) of the filtered residual that the encoder's quantization alone makes: a white
    position error of variance ``quantum**2 / 12`` through the model's inertia and viscous terms
    (second and central differences) and the zero-phase Butterworth of ``order`` at ``cutoff`` Hz
    (applied twice). Checked on a truncating 0.1 um encoder at 1 kHz (P-P loop, 18.8 kg): 0.037 N
    predicted, 0.039 N measured."""
    w = np.linspace(1e-6, np.pi, 20001)
    sos = scipy.signal.butter(order, cutoff, fs=1.0 / ts, output="sos")
    _, h = scipy.signal.sosfreqz(sos, worN=w)
    g = mass / ts**2 * (2.0 * np.cos(w) - 2.0) + 1j * viscous * np.sin(w) / ts
    power = np.trapezoid(np.abs(g) ** 2 * np.abs(h) ** 4, w) / np.pi
    return float(np.sqrt(quantum**2 / 12.0 * power))


def known_direction(y: np.ndarray, quantum: float) -> np.ndarray:
    """Samples where the position path tells the direction of motion over ``[t_k-2, t_k+2]``:
    every one of those four steps moves the same way (at least one count each: a stage that
    sticks for part of a sample, at a few counts per sample, shows as a zero step)."""
    y = np.asarray(y, dtype=float)
    n = len(y)
    out = np.zeros(n, dtype=bool)
    if n < 5:
        return out
    d = np.diff(y)
    up = d > 0
    down = d < 0
    # Steps k-2..k+1 are d[k-2], d[k-1], d[k], d[k+1]; sample k = 2..n-3.
    mono_up = up[:-3] & up[1:-2] & up[2:-1] & up[3:]
    mono_down = down[:-3] & down[1:-2] & down[2:-1] & down[3:]
    out[2:-2] = mono_up | mono_down
    return out


def source_of(run: Run) -> str:
    return str(run.meta.get("source", "record"))


class Residual:
    """The residual of ``plant`` on ``run`` and the machinery to fit regressor columns to it.

    Attributes: ``ts`` (s), ``y, v, a, u`` at full rate (m, m/s, m/s**2, N: ``u`` is the edge
    force), ``raw`` (unfiltered residual, N), ``filtered`` (N), ``idx`` (full-rate indices of the
    fitted samples: moving, away from the ends, decimated), ``z = filtered[idx]``, ``fold``
    (block label per fitted sample), ``n_eff`` (effectively independent samples), ``quantum`` (m).
    """

    def __init__(self, run: Run, plant: Plant, settings: DiagnosisSettings = DiagnosisSettings()):
        ts = run.ts
        self.ts = ts
        self.settings = settings
        self.cutoff = float(min(settings.regression_lowpass_hz, 0.2 / ts))
        self.features = FeatureMap(regression_lowpass_hz=self.cutoff)
        self.y, self.v, self.a = self.features.motion(run.y, ts)
        self.u = edge_force(run.u)
        self.t = np.asarray(run.t, dtype=float)
        self.plant = plant
        self.raw = self.u - plant.inverse_force(self.y, self.v, self.a, u=self.u)
        self.quantum = encoder_quantum(run.y)
        self.v_filtered = self.features.regression_filter(self.v, ts)
        self.v_peak = float(np.quantile(np.abs(self.v_filtered), 0.99))
        self.v_floor = max(0.5 * self.quantum / ts, 1e-4 * self.v_peak)
        keep = known_direction(run.y, self.quantum) & (np.abs(self.v) >= self.v_floor)
        # The velocity cannot reach zero inside the window at the acceleration the applied force
        # gives through the model over either held sample (the force, not the second
        # difference, which carries the encoder's quantization; margin 1.2): a stage that stops
        # for part of a sample (stick-slip under dither) holds less than its sliding friction
        # there, which would read as a low-speed effect.
        held = np.asarray(run.u, dtype=float)
        rest = plant.inverse_force(self.y, self.v, np.zeros_like(self.v), u=self.u)
        swing = np.maximum(np.abs(held - rest), np.abs(np.r_[held[:1], held[:-1]] - rest))
        keep &= np.abs(self.v) >= 1.2 * swing / plant.mass * ts
        edge = max(int(np.ceil(4.0 / (self.cutoff * ts))), 10)
        keep[:edge] = False
        keep[-edge:] = False
        self.weight = keep.astype(float)
        self.coverage = self.features.regression_filter(self.weight, ts)
        self.filtered = self.filter(self.raw)
        self.u_filtered = self.filter(self.u)
        self.decimation = max(1, int(1.0 / (4.0 * self.cutoff * ts)))
        idx = np.flatnonzero((self.coverage >= 0.9) & keep)
        self.idx = idx[:: self.decimation]
        n = len(self.idx)
        moving_pos = np.mean(self.v_filtered[self.idx] > 0) if n else 0.0
        self.n_eff = float(keep.sum() * min(1.0, 2.0 * self.cutoff * ts))
        if n < 20 * settings.folds or self.n_eff < 200 or min(moving_pos, 1 - moving_pos) < 0.05:
            raise UserError(f"{source_of(run)}: too little excitation to identify anything: "
                            f"{keep.sum() * ts:.2f} s of motion above {self.v_floor:.3g} m/s "
                            f"({100 * moving_pos:.0f} % of it in +y); need motion in both "
                            f"directions for at least {200 / (2 * self.cutoff):.1f} s")
        self.z = self.filtered[self.idx]
        self.force_rms = float(np.sqrt(np.mean(self.u_filtered[self.idx] ** 2)))
        self.cache: dict = {}  # columns the searches reuse between selection steps
        self.fold = np.minimum((np.arange(n) * settings.folds) // n, settings.folds - 1)

    def filter(self, x: np.ndarray) -> np.ndarray:
        """The parallel filter along axis 0: standstill samples zeroed, zero-phase low-pass."""
        x = np.asarray(x, dtype=float)
        w = self.weight if x.ndim == 1 else self.weight[:, None]
        return self.features.regression_filter(x * w, self.ts)

    def columns(self, cols: dict[str, np.ndarray]) -> np.ndarray:
        """Full-rate regressor columns -> filtered, at the fitted samples, shape (n, k)."""
        if not cols:
            return np.zeros((len(self.idx), 0))
        return self.filter(np.column_stack(list(cols.values())))[self.idx]

    def quantization_floor(self) -> float:
        """What the encoder's quantization alone makes of this residual (N RMS; see
        :func:`quantization_floor`): no model of this record goes below it."""
        return quantization_floor(self.quantum, self.ts, self.cutoff, self.plant.mass,
                                  self.plant.viscous, self.features.lowpass_order)

    def rms(self) -> float:
        """RMS (N) of the filtered residual over the fitted samples."""
        return float(np.sqrt(np.mean(self.z**2)))

    def spectrum(self) -> tuple[np.ndarray, np.ndarray]:
        """Welch amplitude spectral density of the unfiltered residual: (Hz, N/sqrt(Hz))."""
        nper = min(len(self.raw), 2 ** int(np.log2(max(256, 1.0 / self.ts))))
        f, p = scipy.signal.welch(self.raw - self.raw.mean(), fs=1.0 / self.ts, nperseg=nper)
        return f, np.sqrt(p)

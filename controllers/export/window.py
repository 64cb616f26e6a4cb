"""A feedforward in window form: the force the replay applies at sample k from ``r[k-lag..k+lead]``.

The product's replay applies ``u_ff = held_force(p)``, ``p`` the model's force at the sample
instants (:mod:`clm_sim.features`): ``u_ff[k] = (p[k] + p[k+1])/2``. ``p[j]`` reads the central
differences ``v[j] = (r[j+1] - r[j-1])/(2 ts)``, ``a[j] = (r[j+1] - 2 r[j] + r[j-1])/ts**2``:

* LIP: ``p = m a + fv v + fc sign v + fk r`` (+ effects of ``(r, v, that force)``): lag 1, lead 2;
* PGNN: ``p = theta . filter(T) + f_NN(filter(T))``, ``T = [a, v, sign v, r]``, where ``filter`` is
  the zero-phase Butterworth of the regression (``sosfiltfilt``). That filter is an IIR run
  forwards and backwards, so ``p[j]`` depends on the whole record. Its impulse response decays
  geometrically; :func:`filtfilt_kernel` cuts it where the discarded tail is below ``tol``
  (default 1e-15 of its sum), so the window form is the exact FIR equivalent to that tolerance,
  ``h[-M..M]``: lag ``M + 1``, lead ``M + 2`` (569 + 1 and + 2 for the default 250 Hz, order 4, at
  10 kHz). On a record the Python filter also has ends
  (odd padding, steady-state start); where the reference rests at both ends longer than the
  window, clamping the reference at its ends (:meth:`WindowFeedforward.apply`) gives the same
  values there too.

Not exportable as a window (refused with a ``UserError``): a position low-pass before the
differences (``position_lowpass_hz``) and pre-sliding friction (a state along the whole path).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
import scipy.signal

from clm_sim.errors import UserError
from clm_sim.features import lip_regressors
from clm_sim.plant import THETA_NAMES
from clm_sim.namespace import NUMPY
from clm_sim.rigid_body import rigid_body, rigid_body_columns
from controllers.activations import ACTIVATIONS

DEFAULT_TOL = 1e-15
# The longest impulse response (s) of a filter that is exported: the product's default (250 Hz)
# lasts 0.1 s at 10 kHz; one of seconds is a cut-off typed in the wrong unit, and the work to
# export it grows with its square.
MAX_RESPONSE_S = 4.0


def filtfilt_kernel(order: int, cutoff_hz: float, ts: float,
                    tol: float = DEFAULT_TOL) -> np.ndarray:
    """Impulse response ``h[-M..M]`` (length ``2M+1``, symmetric) of ``sosfiltfilt`` with the
    Butterworth low-pass of ``order`` and ``cutoff_hz`` at sample time ``ts`` (s) on an infinite
    record, cut where the discarded tail sums to less than ``tol`` times ``sum |h|``."""
    nyquist = 0.5 / ts
    if not 0 < cutoff_hz < nyquist:
        raise UserError(f"export: filter cut-off {cutoff_hz:g} Hz is not below the Nyquist "
                        f"frequency {nyquist:g} Hz")
    sos = scipy.signal.butter(order, cutoff_hz, fs=1.0 / ts, output="sos")
    n = 256
    while True:
        impulse = np.zeros(n)
        impulse[0] = 1.0
        g = scipy.signal.sosfilt(sos, impulse)
        if np.sum(np.abs(g[n // 2:])) < 1e-3 * tol * np.sum(np.abs(g)):
            break
        n *= 2
        if n * ts > MAX_RESPONSE_S:  # before the correlation below, which is O(n^2)
            raise UserError(f"export: the {cutoff_hz:g} Hz filter's impulse response does not "
                            f"decay within {MAX_RESPONSE_S:g} s, the longest exported (a cut-off "
                            f"this low is not a feedforward's filter: is it in Hz?)")
    # Subnormal tail values multiply 100x slower and change no sum at this tolerance: flushed
    # (the kernel is bit-identical; a 12 Hz filter at 10 kHz took 4 s, now 0.6 s).
    g[np.abs(g) < 1e-290] = 0.0
    full = np.correlate(g, g, mode="full")  # forward then backward: the autocorrelation
    mid = len(g) - 1
    half = full[mid:]
    total = np.sum(np.abs(full))
    tail = np.cumsum(np.abs(half[::-1]))[::-1]  # tail[j] = sum_{i >= j} |h[i]|, one side
    m = int(np.argmax(2.0 * tail < tol * total)) - 1  # keep |i| <= m
    m = max(m, 0)
    return np.concatenate([half[m:0:-1], half[:m + 1]])


@dataclass(frozen=True)
class Network:
    """The PGNN's network in plain arrays (float64): ``z = (f - input_mean)/input_std``, then
    ``h = act(W h + b)`` per hidden layer and ``out_w . h + out_b`` (N)."""

    input_mean: np.ndarray
    input_std: np.ndarray
    layers: tuple[tuple[np.ndarray, np.ndarray], ...]
    activation: str
    out_w: np.ndarray
    out_b: float

    def __post_init__(self):
        if self.activation not in ACTIVATIONS:
            raise UserError(f"export: activation {self.activation!r} is not exportable")

    def __call__(self, f: np.ndarray) -> np.ndarray:
        h = (f - self.input_mean) / self.input_std
        for w, b in self.layers:
            h = activate(self.activation, h @ w.T + b)
        return h @ self.out_w + self.out_b


def activate(name: str, x: np.ndarray) -> np.ndarray:
    """The activation ``name``'s law on numpy arrays (e^x of a saturated unit may overflow to
    inf where the law then takes its limit)."""
    with np.errstate(over="ignore"):
        return ACTIVATIONS[name].law(x, NUMPY)


@dataclass(frozen=True)
class WindowFeedforward:
    """A feedforward as a function of a window of reference samples.

    ts: sample time (s); theta: physical parameters (``THETA_NAMES``, SI); effects: named
    effects added to the physical force (LIP with effects); kernel: the regression filter's FIR
    ``h[-M..M]`` (``None`` without a network); network: the PGNN's network; source: what the
    model came from (one line, for the header and the metadata).
    """

    ts: float
    theta: dict[str, float]
    source: str
    kind: str = "lip"
    effects: tuple = ()
    kernel: np.ndarray | None = None
    network: Network | None = None
    filter: dict = field(default_factory=dict)

    def __post_init__(self):
        for e in self.effects:
            if e.path_dependent:
                raise UserError("export: pre-sliding friction has a state along the whole path; "
                                "it has no window form and is not exportable")
        if (self.kernel is None) != (self.network is None):
            raise ValueError("kernel and network go together")
        if self.network is not None and self.effects:
            raise ValueError("a PGNN carries no effects")

    @property
    def half(self) -> int:
        """``M``: half-length of the filter kernel (0 without a network)."""
        return 0 if self.kernel is None else (len(self.kernel) - 1) // 2

    @property
    def lag(self) -> int:
        """Samples before ``k`` read: the kernel's half-length plus one (central difference)."""
        return self.half + 1

    @property
    def lead(self) -> int:
        """Samples after ``k`` read: one more than ``lag`` (the held average takes ``p[k+1]``)."""
        return self.half + 2

    @property
    def width(self) -> int:
        return self.lag + 1 + self.lead

    # -- the computation, in numpy (the oracle the C and the ONNX graph are checked against) --
    def forward_filter(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """The causal half of the zero-phase filter: second-order sections ``sos`` (as scipy),
        their steady state per unit input ``zi``, and the causal impulse response ``g[0..M]``
        (``kernel`` is the autocorrelation of the untruncated ``g``). A streaming form runs the
        sections forwards on the features as they come (exact, with state) and ``g`` backwards
        as an FIR over the next ``M`` samples."""
        if self.network is None or not self.filter.get("cutoff_hz"):
            raise ValueError("no zero-phase filter in this feedforward")
        sos = scipy.signal.butter(self.filter["order"], self.filter["cutoff_hz"],
                                  fs=1.0 / self.ts, output="sos")
        impulse = np.zeros(self.half + 1)
        impulse[0] = 1.0
        return sos, scipy.signal.sosfilt_zi(sos), scipy.signal.sosfilt(sos, impulse)

    def point_force(self, w: np.ndarray) -> np.ndarray:
        """``p[j]`` (N) from windows ``w`` (B, 2M+3) = ``r[j-M-1 .. j+M+1]`` (m)."""
        m, ts, th = self.half, self.ts, self.theta
        c = m + 1
        if self.network is None:  # a LIP: theta and the effects on the raw differences
            r0 = w[:, c]
            v = (w[:, c + 1] - w[:, c - 1]) / (2.0 * ts)
            a = (w[:, c + 1] - 2.0 * w[:, c] + w[:, c - 1]) / (ts * ts)
            p = rigid_body(th, a, v, np.sign(v), r0)
            base = p
            for e in self.effects:
                p = p + e.force(r0, v, base)
            return p
        # A PGNN: theta . filt(T) + f_NN(filt(T)), both parts on the filtered features (as
        # fitted, PGNNFeedforward.predict_parts); a PGNN carries no effects.
        f = self.features(w)
        return f @ self.theta_vector() + self.network(f)

    def features(self, w: np.ndarray) -> np.ndarray:
        """The features ``[a, v, sign v, y]`` (SI, (B, 4)) that theta and the network read at
        ``j`` from windows ``w`` (B, 2M+3) = ``r[j-M-1 .. j+M+1]`` (m): a PGNN's filtered by the
        FIR of its regression filter (raw without one, and for a LIP)."""
        m, ts = self.half, self.ts
        c = m + 1
        if self.network is None or m == 0:  # the raw features
            r0 = w[:, c]
            v = (w[:, c + 1] - w[:, c - 1]) / (2.0 * ts)
            a = (w[:, c + 1] - 2.0 * w[:, c] + w[:, c - 1]) / (ts * ts)
            return lip_regressors(r0, v, a)
        # The features at every instant of the window, differenced as the product does, then
        # the filter's FIR.
        va = (w[:, 2:] - w[:, :-2]) / (2.0 * ts)
        aa = (w[:, 2:] - 2.0 * w[:, 1:-1] + w[:, :-2]) / (ts * ts)
        h = self.kernel
        return np.column_stack([column @ h for column in
                                rigid_body_columns(aa, va, np.sign(va), w[:, 1:-1])])

    def theta_vector(self) -> np.ndarray:
        """``theta`` in the order of the features ``[a, v, sign v, y]``: mass, viscous, coulomb,
        stiffness."""
        return np.array([self.theta[name] for name in THETA_NAMES])

    def __call__(self, windows: np.ndarray) -> np.ndarray:
        """``u_ff[k]`` (N) from windows (B, lag+1+lead) = ``r[k-lag .. k+lead]`` (m)."""
        windows = np.asarray(windows, dtype=np.float64)
        if windows.ndim != 2 or windows.shape[1] != self.width:
            raise ValueError(f"expected windows of shape (B, {self.width}), got {windows.shape}")
        return 0.5 * (self.point_force(windows[:, :-1]) + self.point_force(windows[:, 1:]))

    def windows(self, r: np.ndarray) -> np.ndarray:
        """Every window of a record ``r`` (m), shape (N, width); the record is held at its ends
        (a reference that rests before and after)."""
        r = np.asarray(r, dtype=np.float64)
        padded = np.concatenate([np.full(self.lag, r[0]), r, np.full(self.lead, r[-1])])
        return np.lib.stride_tricks.sliding_window_view(padded, self.width)

    def apply(self, r: np.ndarray, chunk: int = 2048) -> np.ndarray:
        """``u_ff`` (N) per sample of a record ``r`` (m), held at its ends (``chunk`` windows
        at a time: a PGNN's windows of a long record would not fit in memory at once)."""
        w = self.windows(r)
        return np.concatenate([self(w[i:i + chunk]) for i in range(0, len(w), chunk)])

    def describe(self) -> str:
        """One paragraph on the model (for the C header and the ONNX doc string)."""
        th = ", ".join(f"{k} {self.theta[k]:.6g}" for k in THETA_NAMES)
        text = f"{self.kind.upper()} feedforward from {self.source}; theta: {th}"
        if self.effects:
            text += "; effects: " + "; ".join(
                e.type + " " + ", ".join(f"{k} {v}" for k, v in e.parameters().items())
                for e in self.effects)
        if self.network is not None and not self.filter.get("cutoff_hz"):
            widths = ",".join(str(len(b)) for _, b in self.network.layers)
            text += (f"; network: hidden ({widths}) {self.network.activation} on the unfiltered "
                     f"features [a, v, sign v, y]")
        elif self.network is not None:
            widths = ",".join(str(len(b)) for _, b in self.network.layers)
            text += (f"; network: hidden ({widths}) {self.network.activation} on the features "
                     f"[a, v, sign v, y] filtered by a {self.filter['order']}th-order zero-phase "
                     f"Butterworth at {self.filter['cutoff_hz']:g} Hz (FIR of {len(self.kernel)} "
                     f"taps, tail below {self.filter['tol']:.0e})")
        return text


def from_lip(lip, ts: float, source: str) -> WindowFeedforward:
    """The window form of a fitted :class:`controllers.lip.LIPFeedforward` at sample time ``ts``."""
    _check_features(lip.features)
    return WindowFeedforward(ts=float(ts), theta=dict(lip.theta_), source=source, kind="lip",
                             effects=tuple(lip.effects_))


def from_pgnn(model, ts: float, source: str, tol: float = DEFAULT_TOL) -> WindowFeedforward:
    """The window form of a fitted :class:`controllers.pgnn.PGNNFeedforward` at ``ts`` (s)."""
    features = model.features
    _check_features(features)
    mlp = model.network_.mlp
    net = Network(
        input_mean=mlp.input_mean.detach().numpy().copy(),
        input_std=mlp.input_std.detach().numpy().copy(),
        layers=tuple((layer.weight.detach().numpy().copy(), layer.bias.detach().numpy().copy())
                     for layer in mlp.hidden),
        activation=model.settings.activation,
        out_w=mlp.out.weight.detach().numpy()[0].copy(),
        out_b=float(mlp.out.bias.detach().numpy()[0]))
    cutoff = features.regression_lowpass_hz
    if cutoff is None:
        kernel = np.ones(1)
    else:
        kernel = filtfilt_kernel(features.lowpass_order, cutoff, ts, tol)
    return WindowFeedforward(ts=float(ts), theta=dict(model.theta_), source=source, kind="pgnn",
                             kernel=kernel, network=net,
                             filter={"order": features.lowpass_order, "cutoff_hz": cutoff or 0.0,
                                     "tol": tol})


def _check_features(features) -> None:
    if features.position_lowpass_hz is not None:
        raise UserError("export: a position low-pass before the differences "
                        "(features.position_lowpass_hz) is not exportable")

"""The logged run: one record type for simulated and measured data.

Every signal is a 1-D float64 array of the same length, sampled at ``t`` (s):
``r`` reference (m), ``y`` measured position (m), ``y_true`` true position (m, NaN if unknown),
``u`` total force applied to the plant (N), ``u_fb`` feedback part, ``u_ff`` feedforward part,
``dither`` injected excitation (N, NaN if unknown), ``e = r - y`` (m). ``meta`` holds the resolved
config, seed and versions. Its files are read and written by :mod:`clm_sim.records`.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

SIGNALS = ("t", "r", "y", "y_true", "u", "u_fb", "u_ff", "dither", "e")


@dataclass(frozen=True)
class Run:
    """A logged closed-loop run: one record type for simulated and measured data.

    Every signal is a 1-D float64 array of one length, sampled at ``t``; a signal that is not
    known (``None``) is NaN (``e`` defaults to ``r - y``). ``ts`` is the sample time from the
    time stamps; ``mae``, ``rms`` and ``max`` are the tracking-error metrics (m).
    ``clm_sim.records.write.save_npz``, ``save_csv`` and ``save_mat`` write one;
    :func:`~clm_sim.records.read.load_record` reads one back.

    Parameters
    ----------
    t : ndarray
        Time stamps, s.
    r : ndarray
        Reference position, m.
    y : ndarray
        Measured position, m.
    u : ndarray
        Total force applied to the plant, N.
    y_true : ndarray, optional
        True position, m (a simulation knows it).
    u_fb, u_ff : ndarray, optional
        Feedback and feedforward parts of ``u``, N.
    dither : ndarray, optional
        Injected excitation, N.
    e : ndarray, optional
        Tracking error ``r - y``, m.
    meta : dict
        The resolved config, seed and versions of a simulated run; the source of a loaded one.

    Raises
    ------
    ValueError
        A signal that is not 1-D or not of the length of ``t``.

    Examples
    --------
    >>> import numpy as np
    >>> from clm_sim import Run
    >>> t = np.arange(5) * 1e-4
    >>> run = Run(t=t, r=np.zeros(5), y=np.full(5, 1e-6), u=np.ones(5))
    >>> run.ts, run.mae                     # s, m
    (0.0001, 1e-06)
    >>> bool(np.isnan(run.dither).all())    # not known
    True
    """

    t: np.ndarray
    r: np.ndarray
    y: np.ndarray
    u: np.ndarray
    y_true: np.ndarray | None = None
    u_fb: np.ndarray | None = None
    u_ff: np.ndarray | None = None
    dither: np.ndarray | None = None
    e: np.ndarray | None = None
    meta: dict = field(default_factory=dict)

    def __post_init__(self):
        n = np.shape(self.t)[0] if np.ndim(self.t) == 1 else -1
        for name in SIGNALS:
            value = getattr(self, name)
            if value is None:
                value = self.r - self.y if name == "e" else np.full(n, np.nan)
            value = np.ascontiguousarray(value, dtype=np.float64)
            if value.ndim != 1 or value.shape[0] != n:
                raise ValueError(f"run signal {name!r} must be 1-D of length {n}, "
                                 f"got shape {value.shape}")
            object.__setattr__(self, name, value)

    def __repr__(self) -> str:
        known = [k for k in SIGNALS[1:] if not np.all(np.isnan(getattr(self, k)))]
        where = self.meta.get("run") or self.meta.get("source")
        timing = f", ts={self.ts:g} s, {self.t[-1] - self.t[0]:.4g} s" if len(self) > 1 else ""
        return (f"Run({len(self)} samples{timing}; {', '.join(known)}"
                + (f"; {str(where)[:60]}" if where else "") + ")")

    @property
    def ts(self) -> float:
        """Sample time (s), from the time stamps."""
        return float((self.t[-1] - self.t[0]) / (len(self.t) - 1))

    def __len__(self) -> int:
        return len(self.t)

    @property
    def mae(self) -> float:
        """Mean absolute tracking error ``mean |e|`` (m)."""
        return float(np.mean(np.abs(self.e)))

    @property
    def rms(self) -> float:
        """Root-mean-square tracking error (m)."""
        return float(np.sqrt(np.mean(self.e ** 2)))

    @property
    def max(self) -> float:
        """Largest absolute tracking error (m)."""
        return float(np.max(np.abs(self.e)))

    def metrics(self) -> dict[str, float]:
        """``{"mae", "rms", "max"}`` of the tracking error (m)."""
        return {"mae": self.mae, "rms": self.rms, "max": self.max}

    def signals(self) -> dict[str, np.ndarray]:
        return {name: getattr(self, name) for name in SIGNALS}

    def moved_origin(self, offset: float) -> "Run":
        """The run seen from an origin ``offset`` m lower: ``y``, ``r`` and ``y_true`` plus
        ``offset``; ``e`` and the forces unchanged. Registers a record whose incremental
        encoder was homed elsewhere to another record's frame."""
        signals = self.signals()
        for name in ("y", "r", "y_true"):
            signals[name] = signals[name] + float(offset)
        return Run(**signals, meta=self.meta)

    def slice(self, start: int, stop: int | None = None) -> "Run":
        """The samples ``start:stop`` as a new run (same meta)."""
        return Run(**{k: v[start:stop] for k, v in self.signals().items()}, meta=self.meta)

"""Closed-loop runs: plant + linear discrete controller + reference (+ feedforward, dither) -> Run."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Protocol

import numpy as np

from clm_sim.errors import UserError, check_ts
from clm_sim.plant import Plant
from clm_sim.run import Run


class DiscreteController(Protocol):
    """A linear discrete controller ``C(z) = b(z^-1)/a(z^-1)`` acting on ``e = r - y``; one that
    also has a ``ts`` attribute (s, e.g. ``controllers.pid.PIDController``) runs at that rate
    only."""

    b: np.ndarray
    a: np.ndarray


@dataclass(frozen=True)
class Dither:
    """Gaussian excitation added to the plant input, for identification in closed loop.

    Parameters
    ----------
    std_n : float
        Standard deviation, N (>= 0; 0: none).
    hold_samples : int
        Each draw is held this many samples (>= 1).

    Raises
    ------
    UserError
        A negative ``std_n`` or a ``hold_samples`` that is not an integer >= 1.

    Examples
    --------
    >>> import numpy as np
    >>> from clm_sim import Dither
    >>> d = Dither(std_n=50.0, hold_samples=2).draw(6, np.random.default_rng(0))  # N
    >>> d.shape, bool(d[0] == d[1]), bool(d[1] == d[2])
    ((6,), True, False)
    """

    std_n: float = 50.0
    hold_samples: int = 1

    def __post_init__(self):
        if not (self.std_n >= 0):
            raise UserError(f"dither: std_n must be >= 0 N, got {self.std_n!r}")
        if not (isinstance(self.hold_samples, int) and self.hold_samples >= 1):
            raise UserError(f"dither: hold_samples must be an integer >= 1, "
                            f"got {self.hold_samples!r}")

    def draw(self, n: int, rng: np.random.Generator) -> np.ndarray:
        """``n`` samples of the dither (N)."""
        if self.std_n == 0:
            return np.zeros(n)
        m = -(-n // self.hold_samples)
        return np.repeat(rng.normal(0.0, self.std_n, m), self.hold_samples)[:n]


def simulate(plant: Plant, controller: DiscreteController, r: np.ndarray, ts: float, *,
             u_ff: np.ndarray | None = None, dither: np.ndarray | None = None,
             meta: dict | None = None) -> Run:
    """Run the closed loop over a reference; the stage starts at rest at ``r[0]``.

    Parameters
    ----------
    plant : Plant
        The machine the loop runs on.
    controller : object
        A linear discrete controller ``C(z) = b(z^-1)/a(z^-1)`` on ``e = r - y`` (attributes
        ``b``, ``a``); one with a ``ts`` attribute (s, e.g. the result of :func:`design_pid`)
        runs at that rate only.
    r : ndarray
        Reference position, m, sampled at ``ts``.
    ts : float
        Sample time, s.
    u_ff, dither : ndarray, optional
        Feedforward and excitation forces, N, per sample, added to the controller output.
    meta : dict, optional
        Stored as the run's ``meta``.

    Returns
    -------
    Run
        Every signal of the loop: ``t, r, y`` (the encoder's reading), ``y_true``, ``u``,
        ``u_fb``, ``u_ff``, ``dither``, ``e``.

    Raises
    ------
    UserError
        If the loop diverges, or if ``controller`` has a ``ts`` other than ``ts``.
    ValueError
        ``u_ff`` or ``dither`` not of the reference's length.

    Examples
    --------
    >>> from clm_sim import PIDDesign, Plant, PointToPoint, design_pid, simulate
    >>> plant = Plant(effects=())
    >>> pid = design_pid(mass=plant.mass, viscous=plant.viscous, stiffness=plant.stiffness,
    ...                  design=PIDDesign(), ts=1e-4)
    >>> r = PointToPoint(points_m=(0.0, 0.01), dwell_s=0.1).sample(1e-4).r
    >>> run = simulate(plant, pid, r, 1e-4)
    >>> len(run), round(run.mae * 1e6)       # samples, µm of mean tracking error
    (4167, 23)
    >>> simulate(plant, pid, r, 1e-3)
    Traceback (most recent call last):
    ...
    clm_sim.errors.UserError: the controller (PIDController) has sample time 0.0001 s ...
    """
    check_ts(getattr(controller, "ts", None), ts, f"the controller ({type(controller).__name__})")
    r = np.ascontiguousarray(r, dtype=np.float64)
    n = r.shape[0]
    u_ff = np.zeros(n) if u_ff is None else np.ascontiguousarray(u_ff, dtype=np.float64)
    dither = np.zeros(n) if dither is None else np.ascontiguousarray(dither, dtype=np.float64)
    if u_ff.shape != (n,) or dither.shape != (n,):
        raise ValueError("u_ff and dither must have the reference's length")
    b = np.ascontiguousarray(controller.b, dtype=np.float64)
    a = np.ascontiguousarray(controller.a, dtype=np.float64)
    # Here, not at the top: numba is a third of a second of imports that a process which only
    # reads a config (Dither) or refuses one never needs; a simulation is 10,000+ steps.
    from clm_sim import kernel

    y, x, u, ufb = (np.empty(n) for _ in range(4))
    status = kernel.closed_loop(r, u_ff, dither, float(r[0]), 0.0, float(plant.encoder_resolution),
                                b, a, plant.kernel_plant(ts), y, x, u, ufb, np.zeros(a.shape[0]))
    if status:
        raise UserError(f"closed loop diverged at t = {(status - 1) * ts:.4f} s; the controller "
                        f"does not stabilise this plant")
    t = np.arange(n) * ts
    return Run(t=t, r=r, y=y, u=u, y_true=x, u_fb=ufb, u_ff=u_ff, dither=dither, e=r - y,
               meta=dict(meta or {}))

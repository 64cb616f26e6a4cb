"""Loop-shaping PID for the linear part of the motor, designed in continuous time and sampled.

The design fixes the 0 dB crossover: the gain ``k`` makes ``|C(j wc) P(j wc)| = 1`` with
``P(s) = 1 / (mass s^2 + viscous s + stiffness)`` [m/N]. The controller is then discretized with
``control.c2d`` and checked on the sampled loop ``Cd(z) Pd(z)`` (``Pd`` = ZOH of ``P``): margins
from ``control.stability_margins``, stability from the closed-loop poles. An unstable or
nonsensical design raises :class:`clm_sim.errors.UserError` and never reaches a simulation.
"""

from __future__ import annotations

import dataclasses
import functools
import math
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from clm_sim.errors import UserError

if TYPE_CHECKING:  # imported where a PID is designed: `control` loads scipy.signal and pyplot
    import control

# Methods of control.c2d that need no extra argument and work for a TransferFunction in
# control 0.10.2 ('gbt' needs alpha; 'matched' fails there).
DISCRETIZATIONS = ("tustin", "bilinear", "zoh", "foh", "backward_diff", "euler")


@dataclass(frozen=True)
class PIDDesign:
    """The shape of a loop-shaping PID; :func:`design_pid` turns it into a controller.

    ``C(s) = k (1 + wi/s) (s/wd + 1)/(s/wt + 1) LP(s)`` with ``wc = 2 pi crossover_hz``,
    ``wi = wc/integrator_ratio``, ``wd = wc/derivative_ratio``, ``wt = wc derivative_ratio``
    (a 'tamed' derivative, low-passed at wt), ``LP`` an optional 2nd-order low-pass; ``k`` is
    chosen so that ``|C(j wc) P(j wc)| = 1`` exactly.

    Parameters
    ----------
    crossover_hz : float
        Crossover frequency, Hz (below Nyquist).
    integrator_ratio : float
        ``wc / wi`` (> 1).
    derivative_ratio : float
        ``wc / wd = wt / wc`` (> 1).
    lowpass_hz : float, optional
        Cut-off of the 2nd-order low-pass, Hz (None: none).
    lowpass_damping : float
        Damping of that low-pass (> 0).
    discretization : str
        Passed to ``control.c2d``; one of ``controllers.pid.DISCRETIZATIONS``.

    Raises
    ------
    UserError
        From :func:`design_pid`, a value out of its range (named).

    Examples
    --------
    >>> from clm_sim import PIDDesign, design_pid
    >>> design = PIDDesign(crossover_hz=50.0, lowpass_hz=1000.0)
    >>> design_pid(mass=18.8, viscous=172.0, stiffness=0.0, design=design, ts=1e-4).summary()
    'PID: crossover 50.0 Hz, phase margin 44.2 deg, gain margin 20.2 dB'
    """

    crossover_hz: float = 30.0
    integrator_ratio: float = 10.0
    derivative_ratio: float = 3.0
    lowpass_hz: float | None = None
    lowpass_damping: float = 0.7
    discretization: str = "tustin"


@dataclass(frozen=True)
class PIDController:
    """A designed, sampled and checked PID.

    ``b``, ``a``: float64 coefficients of C(z) in powers of z^-1, equal length, ``a[0] == 1``
    (input: position error in m, output: force in N). ``kp`` [N/m], ``ki`` [N/(m s)], ``kd``
    [N s/m], ``tau_d`` [s]: the parallel form ``kp + ki/s + kd s/(tau_d s + 1)`` of C(s) without
    the low-pass. ``crossover_hz``, ``phase_margin_deg``, ``gain_margin_db``: measured on the
    discrete loop; the gain margin is the upper one (how much the gain may rise), inf if none.
    """

    design: PIDDesign
    ts: float
    continuous: control.TransferFunction
    discrete: control.TransferFunction
    b: np.ndarray
    a: np.ndarray
    kp: float
    ki: float
    kd: float
    tau_d: float
    crossover_hz: float
    phase_margin_deg: float
    gain_margin_db: float

    def summary(self) -> str:
        """One line with the measured crossover and margins."""
        return (f"PID: crossover {self.crossover_hz:.1f} Hz, phase margin "
                f"{self.phase_margin_deg:.1f} deg, gain margin {self.gain_margin_db:.1f} dB")


def _check(mass: float, viscous: float, stiffness: float, d: PIDDesign, ts: float) -> None:
    def bad(what: str) -> UserError:
        return UserError(f"pid: {what}")

    if not (math.isfinite(ts) and ts > 0):
        raise bad(f"ts must be a positive number of seconds, got {ts}")
    nyquist = 0.5 / ts
    if not (math.isfinite(mass) and mass > 0):
        raise bad(f"mass must be positive (kg), got {mass}")
    if not (math.isfinite(viscous) and math.isfinite(stiffness)):
        raise bad(f"viscous and stiffness must be finite, got {viscous}, {stiffness}")
    if not (math.isfinite(d.crossover_hz) and 0 < d.crossover_hz < nyquist):
        raise bad(f"crossover_hz must be in (0, {nyquist:g}) Hz (Nyquist), got {d.crossover_hz}")
    for name in ("integrator_ratio", "derivative_ratio"):
        value = getattr(d, name)
        if not (math.isfinite(value) and value > 1):
            raise bad(f"{name} must be > 1, got {value}")
    if d.lowpass_hz is not None:
        if not (math.isfinite(d.lowpass_hz) and 0 < d.lowpass_hz < nyquist):
            raise bad(f"lowpass_hz must be in (0, {nyquist:g}) Hz (Nyquist), got {d.lowpass_hz}")
        if not (math.isfinite(d.lowpass_damping) and d.lowpass_damping > 0):
            raise bad(f"lowpass_damping must be positive, got {d.lowpass_damping}")
    if d.discretization not in DISCRETIZATIONS:
        raise bad(f"discretization must be one of {', '.join(DISCRETIZATIONS)}, "
                  f"got {d.discretization!r}")


def design_pid(*, mass: float, viscous: float, stiffness: float, design: PIDDesign,
               ts: float) -> PIDController:
    """Design, discretize and check the PID of ``design`` for the plant and sample time.

    Parameters
    ----------
    mass, viscous, stiffness : float
        Plant ``1 / (mass s^2 + viscous s + stiffness)``: kg, N s/m, N/m.
    design : PIDDesign
        Shape of the controller.
    ts : float
        Sample time of the controller, s.

    Returns
    -------
    PIDController
        The sampled controller: ``b``, ``a`` (C(z) in powers of z^-1, N/m), its ``ts``, the
        parallel gains ``kp``, ``ki``, ``kd``, ``tau_d``, and the crossover and margins
        measured on the discrete loop (``summary()``). It runs at ``ts`` only.

    Raises
    ------
    UserError
        If a parameter is out of range or the sampled closed loop is not stable.

    Examples
    --------
    >>> from clm_sim import PIDDesign, design_pid
    >>> pid = design_pid(mass=18.8, viscous=172.0, stiffness=0.0, design=PIDDesign(), ts=1e-4)
    >>> pid.summary()
    'PID: crossover 30.0 Hz, phase margin 49.7 deg, gain margin 39.4 dB'
    >>> len(pid.b) == len(pid.a), float(pid.a[0])
    (True, 1.0)
    >>> design_pid(mass=18.8, viscous=172.0, stiffness=0.0, design=PIDDesign(), ts=0.01)  # 100 Hz
    Traceback (most recent call last):
    ...
    clm_sim.errors.UserError: pid: the design with crossover 30 Hz gives an unstable closed loop ...

    Notes
    -----
    The design of given arguments is computed once per process and reused (a sweep or a study
    designs the same PID for every task on one plant: a third of a second each); every call
    gets its own ``b`` and ``a``, and shares ``continuous`` and ``discrete`` (python-control
    transfer functions, read only).
    """
    pid = _design(repr((mass, viscous, stiffness, design, ts)), mass, viscous, stiffness,
                  design, ts)
    return dataclasses.replace(pid, b=pid.b.copy(), a=pid.a.copy())


@functools.lru_cache(maxsize=64)
def _design(key: str, mass: float, viscous: float, stiffness: float, design: PIDDesign,
            ts: float) -> PIDController:
    """:func:`design_pid`'s computation. ``key``, the arguments' repr, tells apart what ``==``
    does not (0.0 and -0.0, 1 and 1.0, a float and a numpy scalar), so a reused design is the
    one these exact arguments give. A design that raises is not stored."""
    # Here, not at the top: a config that only names a PIDDesign (every worker, every command
    # that refuses a bad file) need not pay for control, scipy.signal and matplotlib.pyplot.
    import control

    _check(mass, viscous, stiffness, design, ts)
    wc = 2 * math.pi * design.crossover_hz
    wi = wc / design.integrator_ratio
    wd = wc / design.derivative_ratio
    wt = wc * design.derivative_ratio
    plant = control.tf([1.0], [mass, viscous, stiffness])

    def shape(scale: float) -> control.TransferFunction:
        """C(s)/k with every corner frequency multiplied by ``scale``."""
        s = control.tf("s")
        c = (1 + scale * wi / s) * (s / (scale * wd) + 1) / (s / (scale * wt) + 1)
        if design.lowpass_hz is not None:
            wl = scale * 2 * math.pi * design.lowpass_hz
            c = c * control.tf([wl**2], [1, 2 * design.lowpass_damping * wl, wl**2])
        return c

    k = 1.0 / abs(complex((shape(1.0) * plant)(1j * wc)))
    continuous = control.tf(k * shape(1.0).num[0][0], shape(1.0).den[0][0])

    # Parallel form of k (s + wi)(s/wd + 1) / (s (s/wt + 1)), matched coefficient by coefficient.
    tau_d = 1.0 / wt
    ki = k * wi
    kp = k * (1 + wi / wd) - ki * tau_d
    kd = k / wd - kp * tau_d

    # Sample C/k with time in samples (frequencies in rad/sample, period 1): the same C(z) for
    # every c2d method, but the realisation scipy builds stays well-conditioned at kHz
    # frequencies, and the large gain k is applied afterwards.
    unit = control.c2d(shape(ts), 1.0, method=design.discretization)
    num = k * np.asarray(unit.num[0][0], dtype=np.float64)
    den = np.asarray(unit.den[0][0], dtype=np.float64)
    discrete = control.tf(num, den, ts)
    # Powers of z -> powers of z^-1: right-align the numerator under the denominator.
    b = np.concatenate([np.zeros(len(den) - len(num)), num]) / den[0]
    a = den / den[0]

    # Closed-loop poles from state space (the exact ZOH plant and a realisation of Cd) rather
    # than from the loop polynomial, whose clustered roots near z = 1 lose digits.
    plant_d = control.c2d(control.ss(plant), ts, method="zoh")
    loop_ss = control.series(control.ss(discrete), plant_d)
    radius = float(np.max(np.abs(control.feedback(loop_ss, 1).poles())))
    if not radius < 1:
        raise UserError(
            f"pid: the design with crossover {design.crossover_hz:g} Hz gives an unstable closed "
            f"loop (largest |pole| {radius:.4g}); lower crossover_hz"
            + ("" if design.lowpass_hz is None else " or raise lowpass_hz"))

    # Margins on a dense grid of our own: the 'poly' method finds spurious roots with the
    # triple pole at z = 1, and the default 'frd' grid reaches low enough for the phase to be
    # numerical noise around -180 deg. The grid stops just short of Nyquist.
    omega = np.logspace(math.log10(wc / 1e3), math.log10(math.pi / ts * (1 - 1e-9)), 2000)
    z = np.exp(1j * omega * ts)
    response = discrete(z) * plant_d(z)
    gm, pm, _, _, wgc, _ = control.stability_margins(
        control.frd(response, omega, smooth=True), returnall=True)
    if len(pm) == 0:
        raise UserError(f"pid: the loop with crossover {design.crossover_hz:g} Hz never crosses "
                        f"0 dB; check the plant and design")
    # Report the crossover with the smallest phase margin and the upper gain margin (gm > 1).
    # With two integrators the phase sits near -180 deg at low frequency, so there is also a
    # phase crossover below the 0 dB crossover; its gm < 1 is a gain-reduction margin.
    i = int(np.argmin(pm))
    upper = gm[np.asarray(gm) > 1]
    gain_margin_db = float(20 * np.log10(upper.min())) if len(upper) else math.inf

    return PIDController(
        design=design, ts=ts, continuous=continuous, discrete=discrete, b=b, a=a,
        kp=float(kp), ki=float(ki), kd=float(kd), tau_d=float(tau_d),
        crossover_hz=float(wgc[i] / (2 * math.pi)), phase_margin_deg=float(pm[i]),
        gain_margin_db=gain_margin_db)


def filter_error(controller: PIDController, e: np.ndarray) -> np.ndarray:
    """Reference implementation: the controller output for an error sequence, direct form II transposed
    with b, a (zero initial state). The simulator's compiled loop uses exactly the same recursion.

    ``e`` in m (1-D); returns the force in N, float64, same length.
    """
    import scipy.signal  # a test oracle: the simulator never calls it

    return scipy.signal.lfilter(controller.b, controller.a, np.asarray(e, dtype=np.float64))

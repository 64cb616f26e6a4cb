"""An independent closed-loop simulator, written differently from clm-sim's, for foreign records.

Nothing here imports ``clm_sim``'s kernel, plant, controllers or references: the diagnosis must
hold on records that clm-sim's own integrator did not make.

* Plant: ``m*dv/dt = u - fv*v - F_c - F_lugre - F_pos(x)``, integrated per sample by scipy's
  RK45 (Dormand-Prince 5(4), tight tolerances; written out on three scalar states and compiled
  by numba, or ``scipy.integrate.solve_ivp`` itself with ``integrator="solve_ivp"``) with the
  input held. The stick/slip logic, the event's root (brentq on the dense output, as scipy
  finds events) and the controllers run in Python.
  Coulomb friction is handled *event-driven*: a sliding phase runs with a fixed direction until
  the velocity crosses zero (a terminal event); there the stage sticks for the rest of the
  sample if the net force is inside the breakaway band (``coulomb``), else slides on in the
  force's direction.
* A low-speed friction curve on top of Coulomb,
  ``sign(v)*stribeck_peak*exp(-(v/stribeck_velocity)**2)``; a negative peak is a dip (friction
  rising to Coulomb with speed); breakaway ``coulomb + peak``.
* LuGre friction (Canudas de Wit et al. 1995) without a Stribeck peak:
  ``dz/dt = v - sigma0*|v|*z/level``, ``F = sigma0*z + sigma1*dz/dt`` (bristle state ``z`` in m).
* Position forces: a saturating cable-carrier force ``cable*tanh((x - cable_center)/cable_width)``,
  cogging ``amplitude*sin(2 pi x/period + phase)``, a constant ``offset`` (N).
* Encoders that *truncate* (``res*floor(x/res)``), not round.
* Controllers: a PID by pole placement (all three closed-loop poles at ``-omega``) with a
  backward-Euler integrator and filtered derivative, and a P-P cascade without integrator like
  EMPS's (``u = kv*(kp*(r - y) - (y[k] - y[k-2])/(2 ts))``); both expose the equivalent linear law
  ``b, a, reference_b`` for the diagnosis's re-simulation.
* Reference: trapezoidal-velocity moves at several speeds with a dwell between them.
"""

from __future__ import annotations

import dataclasses
import functools
import math
from dataclasses import dataclass

import numba
import numpy as np
import scipy.integrate
import scipy.optimize


@dataclass(frozen=True)
class Stage:
    """The foreign stage (SI units: kg, N*s/m, N, N/m, m)."""

    mass: float = 18.8
    viscous: float = 172.0
    coulomb: float = 7.21
    lugre_level: float = 0.0      # N, LuGre sliding friction (0: none)
    lugre_sigma0: float = 2.0e6   # N/m, bristle stiffness
    lugre_sigma1: float = 0.0     # N*s/m, bristle damping
    cable: float = 0.0            # N, saturation level of the cable-carrier force
    cable_width: float = 0.05     # m
    cable_center: float = 0.0     # m
    cogging: float = 0.0          # N
    cogging_period: float = 0.016  # m
    cogging_phase: float = 0.0    # rad
    offset: float = 0.0           # N
    stribeck_peak: float = 0.0    # N, above Coulomb at standstill (< 0: a dip)
    stribeck_velocity: float = 0.01  # m/s

    def sliding_friction(self, v: float, s: float) -> float:
        """Coulomb plus the low-speed curve (N) for motion in direction ``s``."""
        curve = self.stribeck_peak * math.exp(-((v / self.stribeck_velocity) ** 2))
        return s * (self.coulomb + curve)

    def position_force(self, x: float) -> float:
        f = self.offset
        if self.cable:
            f += self.cable * math.tanh((x - self.cable_center) / self.cable_width)
        if self.cogging:
            f += self.cogging * math.sin(2 * math.pi * x / self.cogging_period + self.cogging_phase)
        return f


class PlantState:
    """Continuous state ``x, v, z`` (m, m/s, m) and the Coulomb direction while sliding."""

    def __init__(self, x0: float):
        self.x, self.v, self.z = x0, 0.0, 0.0


def _lugre(stage: Stage, v: float, z: float) -> tuple[float, float]:
    """(friction force N, dz/dt m/s) of the LuGre bristles."""
    if not stage.lugre_level:
        return 0.0, 0.0
    dz = v - stage.lugre_sigma0 * abs(v) * z / stage.lugre_level
    return stage.lugre_sigma0 * z + stage.lugre_sigma1 * dz, dz


# Dormand-Prince 5(4) with scipy's RK45 coefficients and step-size rule (Hairer, Norsett, Wanner,
# Sec. II.4; scipy.integrate.RK45), written out on the three states: a call of ``solve_ivp`` per
# sample spent most of its time on numpy's per-array overhead for arrays of three, and the same
# arithmetic on Python floats most of it on the interpreter (6 times the CPU of the compiled
# loop; its records are the same bits, benchmarks/bench_reference_sim.py checks that).
# ``advance(..., integrator="solve_ivp")`` keeps the scipy call, which
# tests/test_foreign_records.py compares with this one. Numba freezes these tuples into the
# compiled code (and its cache): they are constants of scipy's RK45.
_A = tuple(tuple(float(a) for a in row[:i]) for i, row in enumerate(scipy.integrate.RK45.A))
_B = tuple(float(b) for b in scipy.integrate.RK45.B)
_E = tuple(float(e) for e in scipy.integrate.RK45.E)
_P = tuple(tuple(float(p) for p in row) for row in scipy.integrate.RK45.P)
_SAFETY, _MIN_FACTOR, _MAX_FACTOR, _EXPONENT = 0.9, 0.2, 10.0, -1 / 5
_EPS = float(np.finfo(float).eps)
_SQRT3 = math.sqrt(3)


@functools.lru_cache(maxsize=64)
def _constants(stage: Stage) -> np.ndarray:
    """The stage's constants for the compiled law, in the order of its fields."""
    return np.array(dataclasses.astuple(stage), dtype=np.float64)


def _law(stage: Stage, s: float, u: float, x: float, v: float, z: float) -> tuple[float, float]:
    """``(dv/dt, dz/dt)`` of ``stage`` sliding in direction ``s`` under the input ``u`` (N)."""
    f, dz = _lugre(stage, v, z)
    fc = stage.sliding_friction(v, s)
    return (u - stage.viscous * v - fc - f - stage.position_force(x)) / stage.mass, dz


@numba.njit(cache=True, nogil=True)
def _derivatives(c, s, u, two, x, v, z):
    """:func:`_law` compiled (the stage's constants ``c`` from :func:`_constants`): the same
    operations in the same order, so the same bits (tests/test_foreign_records.py checks).
    ``two`` is 2.0, passed at run time so that ``** two`` stays a call of the C library's
    ``pow``, as Python's ``** 2`` is (it differs from ``x*x`` in the last bit about once in a
    thousand arguments)."""
    mass, viscous, coulomb, level, sigma0, sigma1 = c[0], c[1], c[2], c[3], c[4], c[5]
    cable, cable_width, cable_center, cogging, period, phase = c[6], c[7], c[8], c[9], c[10], c[11]
    offset, peak, stribeck_velocity = c[12], c[13], c[14]
    if level:
        dz = v - sigma0 * abs(v) * z / level
        f = sigma0 * z + sigma1 * dz
    else:
        f = dz = 0.0
    fc = s * (coulomb + peak * math.exp(-((v / stribeck_velocity) ** two)))
    pos = offset
    if cable:
        pos += cable * math.tanh((x - cable_center) / cable_width)
    if cogging:
        pos += cogging * math.sin(2 * math.pi * x / period + phase)
    return (u - viscous * v - fc - f - pos) / mass, dz


@numba.njit(cache=True, nogil=True)
def _rk45(c, s, u, t, x, v, z, t_end, rtol, atol, watch, two, exponent, K):
    """Integrate ``x' = v, (v', z') = _derivatives(...)`` from ``t`` to ``t_end``, the first step
    the whole interval; with ``watch`` (+1 or -1; 0: no event) stop at the end of the step in
    which ``v*watch`` first crosses zero downwards, with that step's seven stages in ``K``
    (7 x 3) for the dense output. Returns ``(t, x, v, z, crossed, t_old, x_old, v_old, z_old,
    h)``.

    Every sum is written out in the tableau's order, left to right (scipy's RK45 sums some of
    them in another order: the 1e-12 m of the comparison test); compiled without fast-math, so
    none is contracted or reordered, and the records are the same bits as when these lines ran
    in Python. The law is autonomous: the stages' times (the tableau's nodes) are not needed."""
    (a21,), (a31, a32), (a41, a42, a43), (a51, a52, a53, a54), (a61, a62, a63, a64, a65) = _A[1:]
    b1, b2, b3, b4, b5, b6 = _B
    e1, e2, e3, e4, e5, e6, e7 = _E
    fx = v
    fv, fz = _derivatives(c, s, u, two, x, v, z)
    h_abs = t_end - t
    g = v * watch + 1e-300  # > 0 while moving in direction watch
    t_old, x_old, v_old, z_old, h = t, x, v, z, 0.0
    while t < t_end:
        min_step = 10 * abs(np.nextafter(t, np.inf) - t)
        h_abs = max(h_abs, min_step)
        rejected = False
        while True:
            if h_abs < min_step:
                raise RuntimeError("step size too small")
            t_new = min(t + h_abs, t_end)
            h = t_new - t
            h_abs = abs(h)
            # The stages; dx/dt is the velocity of the stage's own state.
            k1x, k1v, k1z = fx, fv, fz
            k2x = v + (k1v * a21) * h
            k2v, k2z = _derivatives(c, s, u, two, x + (k1x * a21) * h, k2x, z + (k1z * a21) * h)
            k3x = v + (k1v * a31 + k2v * a32) * h
            k3v, k3z = _derivatives(c, s, u, two, x + (k1x * a31 + k2x * a32) * h, k3x,
                                    z + (k1z * a31 + k2z * a32) * h)
            k4x = v + (k1v * a41 + k2v * a42 + k3v * a43) * h
            k4v, k4z = _derivatives(c, s, u, two, x + (k1x * a41 + k2x * a42 + k3x * a43) * h,
                                    k4x, z + (k1z * a41 + k2z * a42 + k3z * a43) * h)
            k5x = v + (k1v * a51 + k2v * a52 + k3v * a53 + k4v * a54) * h
            k5v, k5z = _derivatives(c, s, u, two, x + (k1x * a51 + k2x * a52 + k3x * a53
                                                       + k4x * a54) * h, k5x,
                                    z + (k1z * a51 + k2z * a52 + k3z * a53 + k4z * a54) * h)
            k6x = v + (k1v * a61 + k2v * a62 + k3v * a63 + k4v * a64 + k5v * a65) * h
            k6v, k6z = _derivatives(c, s, u, two, x + (k1x * a61 + k2x * a62 + k3x * a63
                                                       + k4x * a64 + k5x * a65) * h, k6x,
                                    z + (k1z * a61 + k2z * a62 + k3z * a63 + k4z * a64
                                         + k5z * a65) * h)
            x_new = x + h * (k1x * b1 + k2x * b2 + k3x * b3 + k4x * b4 + k5x * b5 + k6x * b6)
            v_new = v + h * (k1v * b1 + k2v * b2 + k3v * b3 + k4v * b4 + k5v * b5 + k6v * b6)
            z_new = z + h * (k1z * b1 + k2z * b2 + k3z * b3 + k4z * b4 + k5z * b5 + k6z * b6)
            k7x = v_new
            k7v, k7z = _derivatives(c, s, u, two, x_new, v_new, z_new)
            # The error estimate's RMS norm over the states in order (scipy's
            # ``norm(err / scale) / sqrt(3)``).
            ex = (k1x * e1 + k2x * e2 + k3x * e3 + k4x * e4 + k5x * e5 + k6x * e6 + k7x * e7) * h
            ev = (k1v * e1 + k2v * e2 + k3v * e3 + k4v * e4 + k5v * e5 + k6v * e6 + k7v * e7) * h
            ez = (k1z * e1 + k2z * e2 + k3z * e3 + k4z * e4 + k5z * e5 + k6z * e6 + k7z * e7) * h
            error_norm = math.sqrt((ex / (atol + max(abs(x), abs(x_new)) * rtol)) ** two
                                   + (ev / (atol + max(abs(v), abs(v_new)) * rtol)) ** two
                                   + (ez / (atol + max(abs(z), abs(z_new)) * rtol)) ** two
                                   ) / _SQRT3
            if error_norm < 1:
                factor = _MAX_FACTOR if error_norm == 0 else min(
                    _MAX_FACTOR, _SAFETY * error_norm ** exponent)
                h_abs *= min(1.0, factor) if rejected else factor
                break
            h_abs *= max(_MIN_FACTOR, _SAFETY * error_norm ** exponent)
            rejected = True
        t_old, x_old, v_old, z_old = t, x, v, z
        t, x, v, z = t_new, x_new, v_new, z_new
        fx, fv, fz = k7x, k7v, k7z
        if watch:
            g_new = v * watch + 1e-300
            if g >= 0 and g_new <= 0:  # crossed downwards: the caller finds the root
                for i, (kx, kv, kz) in enumerate(((k1x, k1v, k1z), (k2x, k2v, k2z),
                                                  (k3x, k3v, k3z), (k4x, k4v, k4z),
                                                  (k5x, k5v, k5z), (k6x, k6v, k6z),
                                                  (k7x, k7v, k7z))):
                    K[i, 0], K[i, 1], K[i, 2] = kx, kv, kz
                return t, x, v, z, True, t_old, x_old, v_old, z_old, h
            g = g_new
    return t, x, v, z, False, t_old, x_old, v_old, z_old, h


def _crossing(K, t_old, y_old, h, t, s):
    """The time and state where ``v*s`` crosses zero in the step from ``t_old`` to ``t``: the
    root of the step's dense output (scipy's RK45 interpolant) by brentq, as scipy locates
    events."""
    K = K.tolist()
    Q = [[sum(k[i] * p[j] for k, p in zip(K, _P)) for j in range(4)] for i in range(3)]

    def dense(tt):
        x = (tt - t_old) / h
        p = (x, x * x, x * x * x, x * x * x * x)
        return [y_old[i] + h * sum(q * pp for q, pp in zip(Q[i], p)) for i in range(3)]
    root = scipy.optimize.brentq(lambda tt: dense(tt)[1] * s + 1e-300, t_old, t,
                                 xtol=4 * _EPS, rtol=4 * _EPS)
    return root, dense(root)


def advance(stage: Stage, st: PlantState, u: float, ts: float, *, integrator: str = "rk45",
            constants: np.ndarray | None = None) -> None:
    """Advance ``st`` over one sample with the input ``u`` (N) held (``integrator``: ``rk45``,
    the Dormand-Prince pair above, or ``solve_ivp``, scipy's RK45 through its driver;
    ``constants``: ``_constants(stage)`` where the caller holds them)."""
    c = _constants(stage) if constants is None else constants
    t = 0.0
    guard = 0
    while t < ts and guard < 50:
        guard += 1
        if st.v == 0.0 and stage.coulomb > 0:
            f_lugre = stage.lugre_sigma0 * st.z if stage.lugre_level else 0.0
            net = u - stage.position_force(st.x) - f_lugre
            if abs(net) <= stage.coulomb + stage.stribeck_peak:
                return  # sticks: nothing moves until the input changes
            s = math.copysign(1.0, net)
        else:
            s = math.copysign(1.0, st.v) if st.v != 0.0 else 0.0
        # The velocity cannot reach zero in the rest of the sample when every force together
        # could not stop the stage (bounded deceleration): no event to watch for then.
        bound = (abs(u) + stage.coulomb + abs(stage.stribeck_peak) + stage.viscous * abs(st.v)
                 + abs(stage.offset)
                 + abs(stage.cable) + abs(stage.cogging) + 2 * stage.lugre_level
                 + stage.lugre_sigma1 * 2 * abs(st.v)) / stage.mass
        watch = stage.coulomb > 0 and s != 0.0 and abs(st.v) <= 2 * bound * (ts - t)
        if integrator == "solve_ivp":
            def rhs(_, y, s=s):
                return [y[1], *_law(stage, s, u, *y)]

            def crossing(_, y, s=s):
                return y[1] * s + 1e-300  # >0 while moving in direction s
            crossing.terminal = True
            crossing.direction = -1
            sol = scipy.integrate.solve_ivp(rhs, (t, ts), [st.x, st.v, st.z], method="RK45",
                                            rtol=1e-9, atol=1e-13, first_step=ts - t,
                                            events=crossing if watch else None)
            end, stopped = float(sol.t_events[0][0]) if sol.status == 1 else ts, sol.status == 1
            st.x, st.v, st.z = (float(q) for q in sol.y[:, -1])
        else:
            K = np.empty((7, 3))
            end, st.x, st.v, st.z, stopped, t_old, *y_old, h = _rk45(
                c, s, u, t, st.x, st.v, st.z, ts, 1e-9, 1e-13, s if watch else 0.0, 2.0,
                _EXPONENT, K)
            if stopped:
                end, (st.x, st.v, st.z) = _crossing(K, t_old, y_old, h, end, s)
        t = end
        if stopped:  # stopped at the velocity zero crossing
            st.v = 0.0


@dataclass(frozen=True)
class PID:
    """PID with all closed-loop poles of ``m s^3 + (fv + kd) s^2 + kp s + ki`` at ``-omega``
    (rad/s), derivative filtered with time constant ``1/(10 omega)``, backward Euler."""

    mass: float
    viscous: float
    omega: float
    ts: float

    @property
    def gains(self):
        w = self.omega
        return 3 * self.mass * w * w, self.mass * w**3, max(3 * self.mass * w - self.viscous, 0.0)

    def law(self):
        """``(b, a, reference_b)``: the same controller as a transfer function on ``e``."""
        kp, ki, kd = self.gains
        tau, ts = 1.0 / (10 * self.omega), self.ts
        den_d = np.array([tau + ts, -tau])
        a = np.convolve([1.0, -1.0], den_d)
        b = kp * a + ki * ts * np.concatenate([den_d, [0.0]]) + kd * np.array([1.0, -2.0, 1.0])
        return b / a[0], a / a[0], np.zeros(0)

    def run(self):
        kp, ki, kd = self.gains
        tau, ts = 1.0 / (10 * self.omega), self.ts
        integ = deriv = 0.0
        e_prev = None
        while True:
            r, y = yield
            e = r - y
            integ += ts * e
            deriv = (tau * deriv + (e - (e if e_prev is None else e_prev))) / (tau + ts)
            if e_prev is None:
                deriv = 0.0
            e_prev = e
            yield kp * e + ki * integ + kd * deriv


@dataclass(frozen=True)
class Cascade:
    """P position loop cascaded with a P velocity loop (no integrator): ``kp`` 1/s, ``kv``
    N*s/m; velocity from the two-sample central difference of the measured position."""

    kp: float
    kv: float
    ts: float

    def law(self):
        k, h = self.kv, 0.5 / self.ts
        return (np.array([k * (self.kp + h), 0.0, -k * h]), np.array([1.0]),
                np.array([-k * h, 0.0, k * h]))

    def run(self):
        hist = []
        while True:
            r, y = yield
            hist.append(y)
            y2 = hist[-3] if len(hist) >= 3 else hist[0]
            if len(hist) > 3:
                hist.pop(0)
            yield self.kv * (self.kp * (r - y) - (y - y2) / (2 * self.ts))


def trapezoid_reference(ts: float, *, moves, accel: float = 1.0, dwell: float = 0.2,
                        start: float = 0.0) -> np.ndarray:
    """Positions (m) of trapezoidal-velocity moves ``[(target m, speed m/s), ...]`` with ``accel``
    (m/s^2) and ``dwell`` (s) at rest before each move and at the end."""
    pieces = []
    x = start
    for target, speed in moves:
        pieces.append(np.full(int(round(dwell / ts)), x))
        d = target - x
        dist = abs(d)
        vpk = min(speed, math.sqrt(dist * accel))
        ta = vpk / accel
        tc = dist / vpk - ta
        total = 2 * ta + tc
        t = np.arange(1, int(math.ceil(total / ts)) + 1) * ts
        t = np.minimum(t, total)
        s = np.where(t < ta, 0.5 * accel * t**2,
                     np.where(t < ta + tc, 0.5 * accel * ta**2 + vpk * (t - ta),
                              dist - 0.5 * accel * (total - t) ** 2))
        pieces.append(x + math.copysign(1.0, d) * s)
        x = target
    pieces.append(np.full(int(round(dwell / ts)), x))
    return np.concatenate(pieces)


@dataclass(frozen=True)
class Record:
    t: np.ndarray
    r: np.ndarray
    y: np.ndarray
    u: np.ndarray
    x: np.ndarray


def run_loop(stage: Stage, controller, r: np.ndarray, ts: float, *, resolution: float,
             dither_std: float = 0.0, seed: int = 0, integrator: str = "rk45") -> Record:
    """Closed loop over ``r`` (m): encoder (truncating, ``resolution`` m), controller, held
    input plus white Gaussian dither (``dither_std`` N), plant advanced by :func:`advance`."""
    rng = np.random.default_rng(seed)
    dither = rng.normal(0.0, dither_std, len(r)) if dither_std else np.zeros(len(r))
    st = PlantState(float(r[0]))
    ctrl = controller.run()
    n = len(r)
    y, u, x = np.empty(n), np.empty(n), np.empty(n)
    c = _constants(stage)
    # Python floats (the same values): numpy's scalar arithmetic on the input was slower.
    for k, (rk, dk) in enumerate(zip(np.asarray(r, float).tolist(), dither.tolist())):
        yk = resolution * math.floor(st.x / resolution) if resolution else st.x
        next(ctrl)
        uk = ctrl.send((rk, yk)) + dk
        y[k], u[k], x[k] = yk, uk, st.x
        advance(stage, st, uk, ts, integrator=integrator, constants=c)
    return Record(np.arange(n) * ts, np.asarray(r, float), y, u, x)

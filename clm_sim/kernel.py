"""The compiled 10 kHz loop: encoder, discrete controller and the motor integrated inside each sample.

Numba compiles these functions once per machine (``cache=True``); nothing else in the code base
knows that. The plant step is written so that its pure-Python twin (``plant_step.py_func``) runs the
same arithmetic, which is what the python-control benchmark uses as its oracle.

Integration inside a sample (input held, zero-order hold): ``substeps`` equal sub-steps. On each the
linear part (mass, viscous, stiffness) is propagated exactly with its matrix exponential while the
nonlinear forces are held at their value at the sub-step start. A velocity reversal inside a
sub-step is located (constant-acceleration estimate of the crossing time); at zero velocity the
stage sticks while the net applied force stays within the breakaway band (Karnopp's stick-slip
model), so a stage at rest under a small force never creeps.

Dahl pre-sliding friction is stiff (a bristle stiffness of 1e6-1e8 N/m on a 20 kg mass): inside a
sub-step its state is advanced exactly along the sub-step's displacement ``dx``
(``z1 = s - (s - z0)*exp(-|dx|/length)``) and the force it exerts over the sub-step is taken as the
trapezoidal mean of its start and end values, which makes the sub-step implicit in ``dx``; the
scalar equation is monotone and is solved by safeguarded Newton iteration (:func:`dahl_substep`),
stopped where the bracket or the Newton step is within ``_DAHL_TOL`` of the position (on the
EMPS record one or two iterations; at most 60).

Speed (see ``docs/performance.md``): the helpers are inlined into :func:`closed_loop`, which is
compiled without numba's reference counting (``_nrt=False``; it allocates nothing, its caller
passes the controller state) because counting references to the dozen parameter arrays on every
inlined call cost an atomic update per array per sample, two thirds of the loop's time. Loop
invariants (breakaway levels, the speed above which Stribeck friction is exactly zero) are
computed once per run. None of this changes a bit of the result.
"""

from __future__ import annotations

import math

import numba as nb
import numpy as np

_JIT = dict(cache=True, nogil=True, fastmath=False)
_INLINE = dict(_JIT, inline="always")

# exp(-q) is exactly 0.0 in float64 for q > 745.14; 750 leaves room for the rounding of q.
_EXP_UNDERFLOW = 750.0
# Tolerance of the pre-sliding sub-step's displacement ``dx``, relative to the position
# ``|x| + |dx|``: the equation for ``dx`` carries the rounding of ``x`` (its linear part is
# ``ad @ [x, v] - x``), so a Newton step within about five units in the last place of the
# position is rounding noise, and the new position ``x + dx`` cannot resolve a smaller change.
_DAHL_TOL = 1e-15


@nb.njit(**_JIT)
def _softplus(x):
    """``log(1 + e^x)`` without overflow."""
    return (x if x > 0.0 else 0.0) + math.log1p(math.exp(-abs(x)))


@nb.njit(**_JIT)
def track_factor(x, track):
    """Product of the track ends' overlap fractions ``g(x)`` (see ``clm_sim.effects.TrackEnd``);
    ``track`` rows: start, coil length, fringe (m)."""
    g = 1.0
    for i in range(track.shape[0]):
        start, length, w = track[i, 0], track[i, 1], track[i, 2]
        d = x - start
        lost = w * (_softplus(d / w) - _softplus((d - length) / w)) / length
        d = -x - start
        lost += w * (_softplus(d / w) - _softplus((d - length) / w)) / length
        g *= 1.0 - lost
    return g


@nb.njit(**_INLINE)
def applied_force(x, u, e):
    """Motor force (with ripple and the track ends' factor) minus the position-dependent
    parasitic forces of the effects' arrays ``e`` (``clm_sim.effects.base.EffectArrays``), N.
    ``e.taut`` rows: a taut cable carrier's force, reach and centre (N, m, m;
    ``force*tanh(((x - centre)/reach)**3)``, see ``clm_sim.effects.CableTaut``)."""
    rho = 0.0
    for i in range(e.ripple_amp.shape[0]):
        rho += e.ripple_amp[i] * math.sin(e.ripple_k[i] * x + e.ripple_phase[i])
    f = u * (1.0 + rho)
    if e.track.shape[0] > 0:
        f *= track_factor(x, e.track)
    f -= e.offset
    for i in range(e.taut.shape[0]):
        d = (x - e.taut[i, 2]) / e.taut[i, 1]
        f -= e.taut[i, 0] * math.tanh(d * d * d)
    for i in range(e.harmonic_amp.shape[0]):
        f -= e.harmonic_amp[i] * math.sin(e.harmonic_k[i] * x + e.harmonic_phase[i])
    d = x - e.poly_center
    p = 0.0
    for i in range(e.poly_coef.shape[0] - 1, -1, -1):
        p = p * d + e.poly_coef[i]
    return f - p


@nb.njit(**_INLINE)
def friction_levels(fc, e):
    """``(break_pos, break_neg, v_flat)``: the force a stage at rest must exceed to start moving
    in the positive and negative direction (N, Coulomb + Stribeck peak + asymmetry), and the speed
    (m/s) from which on every Stribeck term is exactly 0.0 in float64."""
    st_sum = 0.0
    v_flat = 0.0
    for i in range(e.stribeck_peak.shape[0]):
        st_sum += e.stribeck_peak[i]
        v_flat = max(v_flat, e.stribeck_velocity[i] * _EXP_UNDERFLOW
                     ** (1.0 / e.stribeck_exponent[i]))
    return fc + st_sum + e.asym[0], fc + st_sum + e.asym[1], v_flat


@nb.njit(**_INLINE)
def friction_extra(v, s, e, v_flat):
    """Friction beyond viscous ``fv*v`` for motion in direction ``s`` (+1/-1), incl. Coulomb part
    added by the caller; returns Stribeck plus direction-dependent terms (N, resisting if > 0*s).
    Above ``v_flat`` (m/s, see :func:`friction_levels`) the Stribeck terms are 0.0 and skipped."""
    f = 0.0
    av = abs(v)
    if not av >= v_flat:  # (a NaN speed goes through, as it would without the shortcut)
        for i in range(e.stribeck_peak.shape[0]):
            f += e.stribeck_peak[i] * math.exp(-((av / e.stribeck_velocity[i])
                                                 ** e.stribeck_exponent[i]))
    if s > 0:
        return f + e.asym[0] + e.asym[2] * v
    return -f - e.asym[1] + e.asym[3] * v


@nb.njit(**_JIT)
def dahl_states(y, length):
    """Normalised Dahl state along the path ``y`` (m) from 0, exact between monotone samples."""
    z = 0.0
    out = np.empty(y.shape[0])
    for k in range(y.shape[0]):
        if k > 0:
            dy = y[k] - y[k - 1]
            if dy != 0.0:
                s = 1.0 if dy > 0.0 else -1.0
                z = s - (s - z) * math.exp(-abs(dy) / length)
        out[k] = z
    return out


@nb.njit(**_INLINE)
def dahl_force(d_f, d_z):
    """Force (N) of the Dahl elements in state ``d_z``."""
    f = 0.0
    for i in range(d_f.shape[0]):
        f += d_f[i] * d_z[i]
    return f


@nb.njit(**_INLINE)
def dahl_move(d_l, d_z, dx):
    """Advance the Dahl states in place along a monotone displacement ``dx`` (m)."""
    if dx != 0.0:
        s = 1.0 if dx > 0.0 else -1.0
        for i in range(d_z.shape[0]):
            d_z[i] = s - (s - d_z[i]) * math.exp(-abs(dx) / d_l[i])


@nb.njit(**_INLINE)
def _dahl_mean(d_f, d_l, d_z, dx):
    """Trapezoidal mean force over a displacement ``dx`` and its derivative ``d/d(dx)``."""
    f = 0.0
    df = 0.0
    s = 1.0 if dx > 0.0 else -1.0
    for i in range(d_f.shape[0]):
        e = math.exp(-abs(dx) / d_l[i])
        z1 = s - (s - d_z[i]) * e
        f += 0.5 * d_f[i] * (d_z[i] + z1)
        df += 0.5 * d_f[i] * (1.0 - s * d_z[i]) * e / d_l[i]
    return f, df


@nb.njit(**_INLINE)
def dahl_substep(x, v, g, ad, bd, d_f, d_l, d_z):
    """One sub-step under the held force ``g`` (N) minus the Dahl force, implicit in ``dx``.

    Solves ``dx = X0 - x + bd0*(g - F(dx))`` with ``F`` the trapezoidal mean Dahl force over
    ``dx`` (increasing in ``dx``, so the root is unique and bracketed by ``F = +-sum d_f``).
    Returns ``(x1, v1, dx)``; the caller commits the states with ``dahl_move(d_l, d_z, dx)``.
    """
    x0 = ad[0, 0] * x + ad[0, 1] * v - x
    fmax = 0.0
    for i in range(d_f.shape[0]):
        fmax += d_f[i]
    lo = x0 + bd[0] * (g - fmax)
    hi = x0 + bd[0] * (g + fmax)
    f0 = dahl_force(d_f, d_z)
    dx = x0 + bd[0] * (g - f0)  # the explicit step: exact for a relaxed, slow bristle
    for _ in range(60):
        f, df = _dahl_mean(d_f, d_l, d_z, dx)
        phi = dx - x0 - bd[0] * (g - f)
        if phi > 0.0:
            hi = dx
        else:
            lo = dx
        if phi == 0.0 or hi - lo <= _DAHL_TOL * (abs(dx) + 1e-12):
            break
        step = dx - phi / (1.0 + bd[0] * df)
        if abs(step - dx) <= _DAHL_TOL * (abs(x) + abs(dx) + 1e-12):
            # Converged: a Newton step at rounding level (often exactly 0, where the explicit
            # step is the root). Newton approaches from one side, so the bracket need not
            # shrink, and bisecting it from here would only walk away from the root and back.
            dx = min(max(step, lo), hi)
            break
        dx = step if lo < step < hi else 0.5 * (lo + hi)
    f, _ = _dahl_mean(d_f, d_l, d_z, dx)
    return x + dx, ad[1, 0] * x + ad[1, 1] * v + bd[1] * (g - f), dx


@nb.njit(**_INLINE)
def advance(x, v, u, p, levels):
    """:func:`plant_step` with the friction levels of :func:`friction_levels` given, as the tuple
    ``levels``."""
    break_pos, break_neg, v_flat = levels
    e = p.effects
    h, ad, bd, mass, fv, fc, fk = p.h, p.ad, p.bd, p.mass, p.viscous, p.coulomb, p.stiffness
    d_f, d_l, d_z = e.dahl_sliding, e.dahl_length, e.dahl_state
    dahl = d_f.shape[0] > 0
    for _ in range(p.substeps):
        fa = applied_force(x, u, e)
        if v == 0.0:
            fn = fa - fk * x
            if dahl:
                fn -= dahl_force(d_f, d_z)
            if fn <= break_pos and fn >= -break_neg:
                continue  # stuck: static friction balances the net force
            s = 1.0 if fn > 0.0 else -1.0
        else:
            s = 1.0 if v > 0.0 else -1.0
        g = fa - s * fc - friction_extra(v, s, e, v_flat)
        if dahl:
            # Dahl's force is continuous in the motion: the reversal event below is for Coulomb.
            x1, v1, dx = dahl_substep(x, v, g, ad, bd, d_f, d_l, d_z)
            if v1 * s >= 0.0 or v == 0.0 or (break_pos == 0.0 and break_neg == 0.0):
                dahl_move(d_l, d_z, dx)
                x, v = x1, v1
                continue
            # A Coulomb reversal inside the sub-step: the event below, Dahl force held.
            g -= dahl_force(d_f, d_z)
        x1 = ad[0, 0] * x + ad[0, 1] * v + bd[0] * g
        v1 = ad[1, 0] * x + ad[1, 1] * v + bd[1] * g
        # Friction continuous at v = 0 (no breakaway force): the exact step needs no event.
        if v1 * s >= 0.0 or v == 0.0 or (break_pos == 0.0 and break_neg == 0.0):
            x, v = x1, v1
            continue
        # Velocity reverses inside this sub-step: stop at the crossing, then stick or slip.
        a0 = (g - fv * v - fk * x) / mass
        t0 = -v / a0 if a0 != 0.0 else h
        if t0 > h:
            t0 = h
        xc = x + v * t0 + 0.5 * a0 * t0 * t0
        if dahl:
            dahl_move(d_l, d_z, xc - x)
        x = xc
        v = 0.0
        rest = h - t0
        fn = applied_force(x, u, e) - fk * x
        if dahl:
            fn -= dahl_force(d_f, d_z)
        if rest <= 0.0 or (fn <= break_pos and fn >= -break_neg):
            continue
        s = 1.0 if fn > 0.0 else -1.0
        a1 = (fn - s * fc - friction_extra(0.0, s, e, v_flat)) / mass
        if a1 * s > 0.0:
            xe = x + 0.5 * a1 * rest * rest
            if dahl:
                dahl_move(d_l, d_z, xe - x)
            x = xe
            v = a1 * rest
    return x, v


@nb.njit(**_JIT)
def plant_step(x, v, u, p):
    """Advance the motor ``p`` (``clm_sim.plant.KernelPlant``: the plant, each part by
    its name) over one held-input sample of ``p.substeps`` sub-steps of ``p.h`` seconds.

    ``p.ad`` (2x2) and ``p.bd`` (2,) propagate ``[x, v]`` over one sub-step for a constant
    force ``G``: ``[x, v] <- ad @ [x, v] + bd * G``. ``p.effects.track`` (n, 3; m): the track
    ends' start, coil length and fringe (:func:`track_factor`); ``taut`` (n, 3; N, m, m): taut
    cable carriers (:func:`applied_force`); ``dahl_sliding, dahl_length`` (N, m): Dahl
    elements' sliding force and length; ``dahl_state``: their states, advanced in place.
    Returns the new ``(x, v)``.
    """
    return advance(x, v, u, p, friction_levels(p.coulomb, p.effects))


@nb.njit(_nrt=False, **_JIT)
def closed_loop(r, u_ff, dither, x0, v0, resolution, b, a, p, y_out, x_out, u_out, ufb_out, z):
    """Run the sampled loop over ``len(r)`` samples, writing into the four output arrays.

    At sample k the encoder reads ``y = resolution*round(x/resolution)`` (``x`` exactly if
    ``resolution == 0``); the controller (direct form II transposed of ``b``, ``a``, state ``z``
    of length ``len(a)``, zeros at the start, left holding the final state) maps ``e = r - y`` to
    ``u_fb``; ``u = u_fb + u_ff + dither`` is held over the sample and the motor ``p`` advanced
    by :func:`plant_step` (its Dahl states advanced in place from the caller's start values).
    Returns 0, or ``k + 1`` if the state became non-finite at sample k (a diverging loop).
    """
    n = r.shape[0]
    order = a.shape[0] - 1
    x, v = x0, v0
    levels = friction_levels(p.coulomb, p.effects)
    for k in range(n):
        y = x if resolution == 0.0 else resolution * math.floor(x / resolution + 0.5)
        e = r[k] - y
        ufb = b[0] * e + z[0]
        for i in range(order - 1):
            z[i] = b[i + 1] * e + z[i + 1] - a[i + 1] * ufb
        if order > 0:
            z[order - 1] = b[order] * e - a[order] * ufb
        u = ufb + u_ff[k] + dither[k]
        y_out[k] = y
        x_out[k] = x
        u_out[k] = u
        ufb_out[k] = ufb
        x, v = advance(x, v, u, p, levels)
        if not (math.isfinite(x) and abs(x) < 1e3):
            return k + 1
    return 0


@nb.njit(_nrt=False, **_JIT)
def open_loop(u, x0, v0, p, x_out, v_out):
    """The motor ``p`` driven by the held inputs ``u`` (N), no controller: ``x_out[k], v_out[k]``
    is the state (m, m/s) at sample k, from ``(x0, v0)`` at sample 0, ``u[k]`` held over
    ``[t_k, t_k+1)`` and the motor advanced by :func:`plant_step` (its Dahl states advanced in
    place from the caller's). Returns 0, or ``k + 1`` if the state became non-finite at sample
    k."""
    n = u.shape[0]
    x, v = x0, v0
    levels = friction_levels(p.coulomb, p.effects)
    for k in range(n):
        x_out[k] = x
        v_out[k] = v
        if k == n - 1:
            break
        x, v = advance(x, v, u[k], p, levels)
        if not (math.isfinite(x) and abs(x) < 1e3):
            return k + 1
    return 0

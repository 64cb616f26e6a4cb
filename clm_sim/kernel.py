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

Speed (see ``benchmarks/README.md``): the helpers are inlined into :func:`closed_loop`, which is
compiled without numba's reference counting (``_nrt=False``; it allocates nothing, its caller
passes the controller state) because counting references to the dozen parameter arrays on every
inlined call cost an atomic update per array per sample, two thirds of the loop's time. Loop
invariants (breakaway levels, the speed above which Stribeck friction is exactly zero) are
computed once per run. None of this changes a bit of the result.
"""

from __future__ import annotations

import math

import numba as nb

_JIT = dict(cache=True, nogil=True, fastmath=False)
_INLINE = dict(_JIT, inline="always")

# exp(-q) is exactly 0.0 in float64 for q > 745.14; 750 leaves room for the rounding of q.
_EXP_UNDERFLOW = 750.0


@nb.njit(**_INLINE)
def applied_force(x, u, hk_amp, hk_k, hk_ph, rp_amp, rp_k, rp_ph, poly, poly_c, offset):
    """Motor force (with ripple) minus the position-dependent parasitic forces, N."""
    rho = 0.0
    for i in range(rp_amp.shape[0]):
        rho += rp_amp[i] * math.sin(rp_k[i] * x + rp_ph[i])
    f = u * (1.0 + rho) - offset
    for i in range(hk_amp.shape[0]):
        f -= hk_amp[i] * math.sin(hk_k[i] * x + hk_ph[i])
    d = x - poly_c
    p = 0.0
    for i in range(poly.shape[0] - 1, -1, -1):
        p = p * d + poly[i]
    return f - p


@nb.njit(**_INLINE)
def friction_levels(fc, st_amp, st_v, st_exp, asym):
    """``(break_pos, break_neg, v_flat)``: the force a stage at rest must exceed to start moving
    in the positive and negative direction (N, Coulomb + Stribeck peak + asymmetry), and the speed
    (m/s) from which on every Stribeck term is exactly 0.0 in float64."""
    st_sum = 0.0
    v_flat = 0.0
    for i in range(st_amp.shape[0]):
        st_sum += st_amp[i]
        v_flat = max(v_flat, st_v[i] * _EXP_UNDERFLOW ** (1.0 / st_exp[i]))
    return fc + st_sum + asym[0], fc + st_sum + asym[1], v_flat


@nb.njit(**_INLINE)
def friction_extra(v, s, st_amp, st_v, st_exp, asym, v_flat):
    """Friction beyond viscous ``fv*v`` for motion in direction ``s`` (+1/-1), incl. Coulomb part
    added by the caller; returns Stribeck plus direction-dependent terms (N, resisting if > 0*s).
    Above ``v_flat`` (m/s, see :func:`friction_levels`) the Stribeck terms are 0.0 and skipped."""
    f = 0.0
    av = abs(v)
    if not av >= v_flat:  # (a NaN speed goes through, as it would without the shortcut)
        for i in range(st_amp.shape[0]):
            f += st_amp[i] * math.exp(-((av / st_v[i]) ** st_exp[i]))
    if s > 0:
        return f + asym[0] + asym[2] * v
    return -f - asym[1] + asym[3] * v


@nb.njit(**_INLINE)
def advance(x, v, u, h, nsub, ad, bd, mass, fv, fc, fk,
            hk_amp, hk_k, hk_ph, rp_amp, rp_k, rp_ph, poly, poly_c, offset,
            st_amp, st_v, st_exp, asym, break_pos, break_neg, v_flat):
    """:func:`plant_step` with the friction levels of :func:`friction_levels` given."""
    for _ in range(nsub):
        fa = applied_force(x, u, hk_amp, hk_k, hk_ph, rp_amp, rp_k, rp_ph, poly, poly_c, offset)
        if v == 0.0:
            fn = fa - fk * x
            if fn <= break_pos and fn >= -break_neg:
                continue  # stuck: static friction balances the net force
            s = 1.0 if fn > 0.0 else -1.0
        else:
            s = 1.0 if v > 0.0 else -1.0
        g = fa - s * fc - friction_extra(v, s, st_amp, st_v, st_exp, asym, v_flat)
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
        x = x + v * t0 + 0.5 * a0 * t0 * t0
        v = 0.0
        rest = h - t0
        fn = applied_force(x, u, hk_amp, hk_k, hk_ph, rp_amp, rp_k, rp_ph, poly, poly_c,
                           offset) - fk * x
        if rest <= 0.0 or (fn <= break_pos and fn >= -break_neg):
            continue
        s = 1.0 if fn > 0.0 else -1.0
        a1 = (fn - s * fc - friction_extra(0.0, s, st_amp, st_v, st_exp, asym, v_flat)) / mass
        if a1 * s > 0.0:
            x = x + 0.5 * a1 * rest * rest
            v = a1 * rest
    return x, v


@nb.njit(**_JIT)
def plant_step(x, v, u, h, nsub, ad, bd, mass, fv, fc, fk,
               hk_amp, hk_k, hk_ph, rp_amp, rp_k, rp_ph, poly, poly_c, offset,
               st_amp, st_v, st_exp, asym):
    """Advance the motor over one held-input sample of ``nsub`` sub-steps of ``h`` seconds.

    ``ad`` (2x2) and ``bd`` (2,) propagate ``[x, v]`` over one sub-step for a constant force
    ``G``: ``[x, v] <- ad @ [x, v] + bd * G``. Returns the new ``(x, v)``.
    """
    break_pos, break_neg, v_flat = friction_levels(fc, st_amp, st_v, st_exp, asym)
    return advance(x, v, u, h, nsub, ad, bd, mass, fv, fc, fk,
                   hk_amp, hk_k, hk_ph, rp_amp, rp_k, rp_ph, poly, poly_c, offset,
                   st_amp, st_v, st_exp, asym, break_pos, break_neg, v_flat)


@nb.njit(_nrt=False, **_JIT)
def closed_loop(r, u_ff, dither, x0, v0, resolution, b, a,
                h, nsub, ad, bd, mass, fv, fc, fk,
                hk_amp, hk_k, hk_ph, rp_amp, rp_k, rp_ph, poly, poly_c, offset,
                st_amp, st_v, st_exp, asym,
                y_out, x_out, u_out, ufb_out, z):
    """Run the sampled loop over ``len(r)`` samples, writing into the four output arrays.

    At sample k the encoder reads ``y = resolution*round(x/resolution)`` (``x`` exactly if
    ``resolution == 0``); the controller (direct form II transposed of ``b``, ``a``, state ``z``
    of length ``len(a)``, zeros at the start, left holding the final state) maps ``e = r - y`` to
    ``u_fb``; ``u = u_fb + u_ff + dither`` is held over the sample and the motor advanced by
    :func:`plant_step`. Returns 0, or ``k + 1`` if the state became non-finite at sample k (a
    diverging loop).
    """
    n = r.shape[0]
    order = a.shape[0] - 1
    x, v = x0, v0
    break_pos, break_neg, v_flat = friction_levels(fc, st_amp, st_v, st_exp, asym)
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
        x, v = advance(x, v, u, h, nsub, ad, bd, mass, fv, fc, fk,
                       hk_amp, hk_k, hk_ph, rp_amp, rp_k, rp_ph, poly, poly_c, offset,
                       st_amp, st_v, st_exp, asym, break_pos, break_neg, v_flat)
        if not (math.isfinite(x) and abs(x) < 1e3):
            return k + 1
    return 0

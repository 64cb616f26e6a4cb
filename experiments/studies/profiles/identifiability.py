"""What the data determine: converged profiles of the PGNN data cost over each physical parameter.

For one network size, parameter ``k`` is held at a value and everything else (the other three
physical parameters, the network) is re-fitted to the data cost alone (lambda = 0, no weight
decay; :meth:`controllers.pgnn.PGNNFeedforward.fit_pinned`). The profile ``V_k(value)`` is the
lowest mean squared error (N**2) the data allow with ``theta_k`` there.

Continuation (:func:`walk`): from the best fit ``theta*``, in both directions, each point starts
from its neighbour's hidden layers (a cold start from one draw scatters by more than the profile
varies). Steps double (``step * scale_k``, then 2x, 4x, ...; larger where ``points`` steps would
not reach the search bound): a profile that rises is found within a few points, one that stays
flat is followed out to the search bound. A direction ends at the first point that rises above
``V_start + delta`` (``rises``) or at the search bound (``bound``: flat all the way).

Convergence, two tests per point (:class:`experiments.studies.profiles.result.Point`): the
optimizer's own, relative (the Gauss-Newton model predicts a relative decrease ``first_order <=
ftol``), and the profile's resolution (it predicts an absolute decrease ``data_cost * first_order``
of at most ``resolution * delta``, and the cost fell by no more than that over the last ``TAIL``
iterations: the point's value is then known to a stated fraction of the threshold it is
compared with). A point stops at the first that holds (``converged`` or
``resolved``) or at its iteration cap; a point that passes neither is an upper bound on the
profile there. The Gauss-Newton prediction is a local model: the study continues the resolved
points it trusts least and records how far their cost still fell.

The threshold ``delta`` is what varies between training records: the sample standard deviation,
over dither-seed records of the same experiment, of the best data cost (below that, a record
cannot tell two values apart by its cost). Beside it, the LIP's own spread over the records and
its autocorrelation-robust (Newey-West) intervals on the profiled record.

The sloppy directions (:func:`sloppy_directions`): eigenvectors of the Gauss-Newton matrix
``J'J`` of the data residual over every parameter (theta, output layer, hidden layers), columns
scaled to unit norm (a unit step of any one parameter alone then moves the force by 1 N rms), so
an eigenvalue is the cost rise (N**2) of a unit step along its vector. The smallest ones say
which combinations the data cannot see: their theta part and the share of the vector on the
network; and per theta direction, what is left of it once the network has absorbed what it can
(the Schur complement of the network block).
"""

from __future__ import annotations

from dataclasses import replace
from typing import Callable

import numpy as np

from clm_sim.plant import THETA_NAMES
from experiments.studies.profiles.result import (LipIntervals, ParameterProfile, Point, Sides,
                                         SloppyDirections, SmallDirection, ThetaDirection,
                                         ValleyRange, Walk)

ENDS = ("rises", "bound")  # why a direction of the continuation ended


TAIL = 10  # iterations over which a fit's last decrease is measured


def point_of(value: float, fit, *, atol: float | None, beta: np.ndarray | None = None,
             tail: float = 0.0, before: Point | None = None) -> Point:
    """The profile point of a fit record (:class:`controllers.pgnn.fit_record.FitRecord`) at
    ``value``, held to its own ``ftol`` and to ``atol`` (N**2); ``before``: the point this fit
    continued (its iterations are added, and its data cost kept as ``confirmed_from``)."""
    point = Point(value=float(value), data_cost=fit.data_cost, stop=fit.stop,
                  iterations=fit.iterations, beta=beta, tail=tail,
                  first_order=fit.first_order, ftol=fit.ftol, atol=atol)
    if before is None:
        return point
    return replace(point, iterations=before.iterations + fit.iterations,
                   continued=fit.iterations, confirmed_from=before.data_cost)


def tail_decrease(history: list) -> float:
    """The fall of the data cost (N**2) over the last ``TAIL`` iterations of a fit's history
    (``controllers.pgnn.fit_record.Iterate`` records, one per iteration)."""
    if len(history) < 2:
        return 0.0
    return float(history[max(0, len(history) - 1 - TAIL)].data - history[-1].data)


def scales(phi: np.ndarray, target: np.ndarray) -> dict[str, float]:
    """Per parameter, the change that alone moves the force by its rms on the data (SI)."""
    rms_f = float(np.sqrt(np.mean(target ** 2)))
    return {name: rms_f / max(float(np.sqrt(np.mean(phi[:, k] ** 2))), 1e-300)
            for k, name in enumerate(THETA_NAMES)}


def search_bounds(start: float, lip: float, scale: float, span: float) -> tuple[float, float]:
    """The values a profile may visit: the hull of the start and theta_LIP, widened by
    ``span * scale`` on both sides."""
    return min(start, lip) - span * scale, max(start, lip) + span * scale


def walk(fit_at: Callable[[float, np.ndarray], Point], start: Point, direction: int, *,
         first_step: float, bound: float, level: float, points: int, refine: int = 0,
         confirm: Callable[[Point], Point] | None = None) -> Walk:
    """Continuation of a profile from ``start`` in ``direction`` (+1 or -1): values
    ``start + direction * h * (1, 3, 7, 15, ...)`` (steps ``h, 2h, 4h, ...``), the last one
    clipped to ``bound``; ``h`` is ``first_step``, or larger where ``points`` such steps would
    not reach ``bound`` (so every direction is decided: it rises or is flat to the bound).
    ``fit_at(value, beta0)`` fits one point from the hidden layers ``beta0`` (the neighbour's).
    A point above ``level`` is first handed to ``confirm`` (None: taken as it is), which
    continues its fit and returns the point it reaches: a rise rests on the point's end state,
    not on where a local stopping test left it. Ends at the first point still above ``level``
    (``rises``) or at ``bound`` (``bound``; the ``points``-th point is there). A rise is then
    bracketed ``refine`` times by bisection (each midpoint started from the inside end,
    confirmed likewise), so that the crossing is located to ``1 / 2**refine`` of the last
    step. Returns the :class:`Walk` (points in the order fitted, the end's reason)."""

    def fit(value: float, beta0: np.ndarray) -> Point:
        point = fit_at(value, beta0)
        if point.data_cost > level and confirm is not None:
            point = confirm(point)
        return point

    reach = abs(bound - start.value)
    out, prev, offset = [], start, 0.0
    step = max(first_step, reach / (2.0 ** points - 1.0))
    for i in range(points):
        offset = reach if i == points - 1 else min(offset + step, reach)
        step *= 2.0
        point = fit(start.value + direction * offset, prev.beta)
        out.append(point)
        if point.data_cost > level:
            inside, outside = prev, point
            for _ in range(refine):
                mid = fit(0.5 * (inside.value + outside.value), inside.beta)
                out.append(mid)
                if mid.data_cost > level:
                    outside = mid
                else:
                    inside = mid
            return Walk(tuple(out), "rises")
        if offset >= reach:
            return Walk(tuple(out), "bound")
        prev = point
    raise AssertionError("walk: the last point is at the bound")  # pragma: no cover


def monotone(costs, tol: float = 0.0) -> bool:
    """Whether ``costs`` never fall by more than ``tol`` from one point to the next."""
    c = np.asarray(costs, dtype=float)
    return bool(np.all(np.diff(c) >= -tol))


def valley_range(values, costs, v_best: float, delta: float, center: float | None = None
                 ) -> ValleyRange:
    """The contiguous block of profile ``values`` around ``center`` (a value of the profile:
    where the continuation started; None or outside the level: the lowest point) where
    ``costs <= v_best + delta``, as a :class:`ValleyRange`; a closed end is where the profile,
    interpolated linearly between points, crosses ``v_best + delta``; open: the block reaches
    the last point on that side (the range's end is then that point)."""
    values, costs = np.asarray(values, float), np.asarray(costs, float)
    order = np.argsort(values)
    values, costs = values[order], costs[order]
    inside = costs <= v_best + delta
    i = int(np.argmin(costs))
    if center is not None:
        j = int(np.argmin(np.abs(values - center)))
        i = j if inside[j] else i
    if not inside[i]:  # the profile never comes within delta of the best fit
        return ValleyRange(None, (False, False))
    lo = hi = i
    while lo > 0 and inside[lo - 1]:
        lo -= 1
    while hi < len(values) - 1 and inside[hi + 1]:
        hi += 1
    level = v_best + delta

    def edge(inner, outer):  # where the profile crosses the level between two points
        c0, c1 = costs[inner] - level, costs[outer] - level
        return float(values[inner] + (values[outer] - values[inner]) * c0 / (c0 - c1))

    low = float(values[0]) if lo == 0 else edge(lo, lo - 1)
    high = float(values[-1]) if hi == len(values) - 1 else edge(hi, hi + 1)
    return ValleyRange((low, high), (lo == 0, hi == len(values) - 1),
                       (float(values[lo]), float(values[hi])))


def in_range(value: float, valley: ValleyRange) -> bool:
    """Whether ``value`` lies in ``valley`` (an open side extends to infinity)."""
    return valley.contains(value)


def parameter_profile(start: Point, down: Walk, up: Walk, v_best: float, delta: float,
                      bounds: tuple[float, float]) -> ParameterProfile:
    """The record of one parameter's profile: its points (lowest value first), each direction's
    end and whether its costs rise monotonically away from the start, and the range within
    ``delta`` of ``v_best``; an open side says why it is open (flat to the search ``bound``)."""
    down_pts = sorted(down.points, key=lambda p: -p.value)  # nearest the start first
    up_pts = sorted(up.points, key=lambda p: p.value)
    pts = tuple(reversed(down_pts)) + (start,) + tuple(up_pts)
    level = v_best + delta
    valley = valley_range([p.value for p in pts], [p.data_cost for p in pts], v_best, delta,
                          center=start.value)
    # A direction that "rises" at a point that passed neither convergence test may not rise:
    # that point is an upper bound on the profile, so the end says so.
    ends = Sides(*(w.end + ("" if w.end != "rises" or all(
        p.settled for p in w.points if p.data_cost > level) else " (not converged)")
        for w in (down, up)))
    mono = Sides(*(monotone([start.data_cost] + [p.data_cost for p in side])
                   for side in (down_pts, up_pts)))
    why_open = (down.end if valley.open[0] else None, up.end if valley.open[1] else None)
    return ParameterProfile(start=start.value, points=pts, bound=tuple(bounds), valley=valley,
                            ends=ends, monotone=mono, why_open=why_open)


def record_threshold(costs: list[float]) -> float:
    """``delta``: the sample standard deviation of the best data cost over training records."""
    c = np.asarray(costs, dtype=float)
    if len(c) < 2:
        raise ValueError("record_threshold: needs at least two records")
    return float(np.std(c, ddof=1))


def sloppy_directions(model, phi: np.ndarray, target: np.ndarray, count: int = 3
                      ) -> SloppyDirections:
    """The sloppy directions of a fitted PGNN's data cost on ``(phi, target)``: the Gauss-Newton
    matrix ``J'J`` over every parameter (theta, output layer, hidden layers), columns scaled to
    unit norm, so that one unit of a parameter moves the force by 1 N rms and an eigenvalue is
    the cost rise (N**2) of a unit step along its vector.

    ``smallest``: its ``count`` smallest eigenpairs, each with the eigenvalue, its ratio to the
    largest, the theta part of the unit vector (in those units; its squared norm is
    ``1 - network_share``) and the network's share. ``theta``: the Schur complement of the
    network block, ``J_theta' (I - P_net) J_theta`` (what is left of each theta direction once
    the network, linearized at the fit, has absorbed what it can), its eigenvalues (N**2 per
    unit, smallest first) and unit eigenvectors in theta: a near-zero eigenvalue is a theta
    combination the network can stand in for."""
    import torch

    from controllers.pgnn.cost import SeparableCost, Weights

    net = model.network_
    cost = SeparableCost(net, phi, target, np.array([model.theta_[k] for k in THETA_NAMES]),
                         Weights(lam_diag=np.zeros(4)), fit_theta=True)
    theta = net.theta.detach().numpy()
    w_out = net.mlp.out.weight.detach().numpy().ravel()
    b_out = float(net.mlp.out.bias.detach().numpy()[0])
    p = np.concatenate([theta, w_out, [b_out], net.get_nonlinear()])
    with torch.no_grad():
        _, jac = cost.full(p, True)
    norms = np.linalg.norm(jac, axis=0)
    norms[norms == 0] = 1.0
    js = jac / norms
    eig, vec = np.linalg.eigh(js.T @ js)
    eig = np.maximum(eig, 0.0)
    smallest = tuple(SmallDirection(float(eig[i]), float(eig[i] / eig[-1]),
                                    dict(zip(THETA_NAMES, map(float, vec[:4, i]))),
                                    float(np.sum(vec[4:, i] ** 2)))
                     for i in range(min(count, len(eig))))
    jt, jn = js[:, :4], js[:, 4:]
    u, sv, _ = np.linalg.svd(jn, full_matrices=False)
    u = u[:, sv > sv[0] * 1e-10]
    rest = jt - u @ (u.T @ jt)
    s_eig, s_vec = np.linalg.eigh(rest.T @ rest)
    return SloppyDirections(float(eig[-1]), smallest, tuple(
        ThetaDirection(float(max(s_eig[i], 0.0)), dict(zip(THETA_NAMES, map(float, s_vec[:, i]))))
        for i in range(4)))


def lip_intervals(phi: np.ndarray, target: np.ndarray) -> LipIntervals:
    """The LIP (least squares of ``target`` on ``phi``'s four columns, named) on the fitting
    samples, with white-noise and Newey-West (autocorrelation-robust) standard errors at the
    automatic bandwidth of Newey and West (1994), the residual's lag-1 autocorrelation and its
    autocorrelation at the lags chosen (:func:`experiments.stats.hac.newey_west`)."""
    from experiments.stats.hac import newey_west

    fit = newey_west(phi, target, lags="auto")
    def named(values):
        return dict(zip(THETA_NAMES, map(float, values)))

    return LipIntervals(named(fit.theta), named(fit.std_white), named(fit.std_newey_west),
                        fit.lag1_autocorr, fit.lags, int(len(target)), fit.autocorr_at_lags)

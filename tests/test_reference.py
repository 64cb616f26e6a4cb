"""Tests for the jerk-limited point-to-point reference (clm_sim.reference)."""

import math

import numpy as np
import pytest

from clm_sim.errors import UserError
from clm_sim.reference import PointToPoint

TS = 1e-4  # s, the 10 kHz sample time

# The bounds are met with equality on the plateaus, where the sampled peak is the bound up to a
# few ulps of rounding in the segment times (divisions, square roots); 1e-9 relative is far above
# that rounding and far below any violation that would matter.
BOUND_RTOL = 1e-9

REFERENCES = {
    "r1": PointToPoint((-0.1, 0.1, -0.1, 0.1, -0.1)),
    "r2": PointToPoint((0.0, 0.17, 0.0, 0.17, 0.0)),
    "r1_no_dwell": PointToPoint((-0.1, 0.1, -0.1, 0.1, -0.1), dwell_s=0.0),
    "repeated_points": PointToPoint((0.0, 0.02, 0.02, -0.03), dwell_s=0.1),
}


def optimal_move_time(d, v, a, j):
    """Closed-form time-optimal rest-to-rest duration (s) over |d| under symmetric v, a, j bounds.

    Derived here independently of the module: the speed-up phase is symmetric, so
    d = v_peak * (speed-up time) when v_max is not reached.
    """
    d = abs(d)
    if d == 0.0:
        return 0.0
    if v >= a**2 / j:  # v_max reachable with an a_max plateau
        if d >= v * (v / a + a / j):
            return d / v + v / a + a / j
    elif d >= 2.0 * v * math.sqrt(v / j):  # v_max reached from pure jerk ramps
        return d / v + 2.0 * math.sqrt(v / j)
    if d >= 2.0 * a**3 / j**2:  # a_max plateau, no cruise
        return a / j + math.sqrt((a / j) ** 2 + 4.0 * d / a)
    return 4.0 * (d / (2.0 * j)) ** (1.0 / 3.0)  # four jerk ramps only


def dwell_windows(ref):
    """(start_s, end_s, point_m) of every standstill, from the closed-form move times."""
    windows, t = [], 0.0
    for i, point in enumerate(ref.points_m):
        windows.append((t, t + ref.dwell_s, point))
        if i + 1 < len(ref.points_m):
            t += ref.dwell_s + optimal_move_time(
                ref.points_m[i + 1] - point,
                ref.max_velocity,
                ref.max_acceleration,
                ref.max_jerk,
            )
    return windows


@pytest.fixture(scope="module", params=sorted(REFERENCES))
def sampled(request):
    ref = REFERENCES[request.param]
    return ref, ref.sample(TS)


def test_shape_and_time_grid(sampled):
    ref, s = sampled
    n = math.ceil(ref.duration_s() / TS) + 1
    for x in (s.t, s.r, s.v, s.a, s.j):
        assert x.dtype == np.float64 and x.shape == (n,)
    np.testing.assert_array_equal(s.t, np.arange(n) * TS)  # t = k * ts exactly


def test_bounds(sampled):
    ref, s = sampled
    assert np.max(np.abs(s.v)) <= ref.max_velocity * (1 + BOUND_RTOL)
    assert np.max(np.abs(s.a)) <= ref.max_acceleration * (1 + BOUND_RTOL)
    assert np.max(np.abs(s.j)) <= ref.max_jerk * (1 + BOUND_RTOL)


def test_duration_is_dwells_plus_optimal_moves(sampled):
    ref, _ = sampled
    end_of_last_dwell = dwell_windows(ref)[-1][1]
    # Sums of a handful of segment times: rounding only.
    assert ref.duration_s() == pytest.approx(end_of_last_dwell, rel=1e-12)


def test_points_reached_exactly(sampled):
    ref, s = sampled
    # Keep 1 us inside each window: its edges come from a different sum of the same times.
    margin = 1e-6
    for start, end, point in dwell_windows(ref):
        inside = (s.t >= start + margin) & (s.t <= end - margin)
        assert inside.sum() >= round(ref.dwell_s / TS) - 2  # at most one sample lost per edge
        assert np.all(s.r[inside] == point)  # bit-exact
        assert np.all(s.v[inside] == 0.0) and np.all(s.a[inside] == 0.0)
    assert s.r[-1] == ref.points_m[-1] and s.v[-1] == 0.0 and s.a[-1] == 0.0


def test_finite_differences_match(sampled):
    """Central differences of r and v agree with the analytic v and a.

    With |r'''| = |j| <= J the central-difference error of r' is at most J ts^2 / 6; a is
    continuous with slope |a'| <= J, so the error of v' is at most J ts / 2. Round-off adds
    ~eps * |r| / ts ~ 1e-13, covered by the extra 1e-10. Both bounds are attained (a sample on
    a jerk switch), so they are tight. np.gradient's first and last values are one-sided
    (first-order) differences and are left out.
    """
    ref, s = sampled
    jmax = ref.max_jerk
    dv = np.abs(np.gradient(s.r, TS) - s.v)[1:-1]
    da = np.abs(np.gradient(s.v, TS) - s.a)[1:-1]
    assert dv.max() <= jmax * TS**2 / 6 + 1e-10
    assert da.max() <= jmax * TS / 2 + 1e-10


@pytest.mark.parametrize(
    ("distance_m", "bounds", "v_reached", "a_reached"),
    [
        pytest.param(1e-4, (0.05, 4.0, 1000.0), False, False, id="short"),
        pytest.param(-5e-4, (0.05, 4.0, 1000.0), False, True, id="medium"),
        pytest.param(0.2, (0.05, 4.0, 1000.0), True, True, id="long"),
        # v_max < a_max^2 / j_max: v_max reached without an a_max plateau.
        pytest.param(0.05, (0.01, 4.0, 1000.0), True, False, id="long_jerk_limited"),
    ],
)
def test_single_move_is_time_optimal(distance_m, bounds, v_reached, a_reached):
    v_max, a_max, j_max = bounds
    start = 0.03
    ref = PointToPoint(
        (start, start + distance_m),
        dwell_s=0.0,
        max_velocity=v_max,
        max_acceleration=a_max,
        max_jerk=j_max,
    )
    # Closed forms for the case this move is in (d = |distance|):
    d = abs(distance_m)
    expected = {
        "short": 4.0 * (d / (2.0 * j_max)) ** (1.0 / 3.0),
        "medium": a_max / j_max + math.sqrt((a_max / j_max) ** 2 + 4.0 * d / a_max),
        "long": d / v_max + v_max / a_max + a_max / j_max,
        "long_jerk_limited": d / v_max + 2.0 * math.sqrt(v_max / j_max),
    }
    case = {(False, False): "short", (False, True): "medium", (True, True): "long"}.get(
        (v_reached, a_reached), "long_jerk_limited"
    )
    assert ref.duration_s() == pytest.approx(expected[case], rel=1e-12)  # rounding only

    s = ref.sample(1e-5)  # fine grid, so plateaus and near-peaks are sampled
    peak_v, peak_a = np.max(np.abs(s.v)), np.max(np.abs(s.a))
    assert peak_v <= v_max * (1 + BOUND_RTOL)
    assert peak_a <= a_max * (1 + BOUND_RTOL)
    assert np.max(np.abs(s.j)) <= j_max * (1 + BOUND_RTOL)
    # A bound is reached on a plateau (sampled, so equal to rounding) or clearly not reached.
    assert bool(peak_v == pytest.approx(v_max, rel=BOUND_RTOL)) is v_reached
    assert bool(peak_a == pytest.approx(a_max, rel=BOUND_RTOL)) is a_reached
    assert s.r[-1] == start + distance_m  # bit-exact end point
    assert np.all(np.sign(s.v) * np.sign(distance_m) >= 0)  # no overshoot or reversal


def test_direction_symmetry():
    up = PointToPoint((0.0, 0.1), dwell_s=0.01).sample(TS)
    down = PointToPoint((0.0, -0.1), dwell_s=0.01).sample(TS)
    for x_up, x_down in ((up.r, down.r), (up.v, down.v), (up.a, down.a), (up.j, down.j)):
        np.testing.assert_array_equal(x_up, -x_down)  # same arithmetic with flipped signs


def test_repeated_point_is_pure_dwell():
    ref = PointToPoint((0.02, 0.02), dwell_s=0.25)
    s = ref.sample(TS)
    assert ref.duration_s() == 0.5
    assert np.all(s.r == 0.02) and not np.any(s.v) and not np.any(s.a) and not np.any(s.j)


@pytest.mark.parametrize(
    ("kwargs", "field"),
    [
        (dict(points_m=(0.1,)), "points_m"),
        (dict(points_m=()), "points_m"),
        (dict(points_m=(0.0, float("nan"))), "points_m"),
        (dict(points_m=(0.0, float("inf"))), "points_m"),
        (dict(points_m=(0.0, "a")), "points_m"),
        (dict(points_m=(0.0, 0.1), dwell_s=-0.1), "dwell_s"),
        (dict(points_m=(0.0, 0.1), dwell_s=float("inf")), "dwell_s"),
        (dict(points_m=(0.0, 0.1), max_velocity=-1.0), "max_velocity"),
        (dict(points_m=(0.0, 0.1), max_velocity=float("nan")), "max_velocity"),
        (dict(points_m=(0.0, 0.1), max_acceleration=0.0), "max_acceleration"),
        (dict(points_m=(0.0, 0.1), max_acceleration=float("inf")), "max_acceleration"),
        (dict(points_m=(0.0, 0.1), max_jerk=-5.0), "max_jerk"),
        (dict(points_m=(0.0, 0.1), max_jerk="fast"), "max_jerk"),
    ],
)
def test_bad_input_raises_user_error(kwargs, field):
    with pytest.raises(UserError, match=f"^reference: {field}") as info:
        PointToPoint(**kwargs)
    assert "\n" not in str(info.value)


def test_message_names_field_and_unit():
    with pytest.raises(UserError, match=r"^reference: max_velocity must be > 0 m/s, got -1$"):
        PointToPoint((0.0, 0.1), max_velocity=-1)


@pytest.mark.parametrize("ts", [0.0, -1e-4, float("nan"), float("inf")])
def test_bad_sample_time_raises_user_error(ts):
    with pytest.raises(UserError, match="^reference: ts"):
        PointToPoint((0.0, 0.1)).sample(ts)

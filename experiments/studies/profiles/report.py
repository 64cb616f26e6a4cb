"""The profiles study's report (``report.md``): per network size the threshold, the profile
ranges beside the LIP's intervals, each point's convergence tests and stops, the confirmed rises,
the check of the resolution test and the sloppy directions of every record's fit; it reads the
typed record (:class:`experiments.studies.profiles.result.SizeRecord`) only.
"""

from __future__ import annotations

import numpy as np

from clm_sim.plant import THETA_NAMES
from experiments.studies.profiles import identifiability as ident
from experiments.studies.profiles.result import SizeRecord


def _g(x: float) -> str:
    return f"{x:.4g}"


def _range_text(e) -> str:
    """A profile's range within delta, each open side saying why it is open."""
    if e.valley.limits is None:
        return "none within δ"
    lo, hi = e.valley.limits
    return ((f"(flat to the {e.why_open[0]}) " if e.valley.open[0] else "")
            + f"[{_g(lo)}, {_g(hi)}]"
            + (f" (flat to the {e.why_open[1]})" if e.valley.open[1] else ""))


def _counts(points) -> tuple[int, int, int]:
    """(relative test passed, resolution test only, neither) over ``points``."""
    rel = sum(p.relative_test for p in points)
    res = sum(p.resolution_test and not p.relative_test for p in points)
    return rel, res, len(points) - rel - res


def to_markdown(sizes: dict[int, SizeRecord]) -> str:
    """The report: per network size the threshold, the profile ranges beside the LIP's
    intervals, the points' convergence tests and stops, the check of the resolution test and
    the sloppy directions of every record's fit."""
    from clm_sim.plant import THETA_UNITS

    lines = ["# What the data determine at λ = 0: converged profiles", ""]
    for hidden, rec in sizes.items():
        li, st, ws = rec.lip_intervals, rec.start, rec.settings
        lines += [f"## n_l = {hidden}", "",
                  f"Best data cost {rec.best_data_cost:.5f} N²; δ = {rec.delta:.3g} N² "
                  f"(standard deviation of the best data cost over {len(rec.seeds)} "
                  f"training records, seeds {', '.join(map(str, rec.seeds))}: "
                  + ", ".join(f"{c:.5f}" for c in rec.best_cost_per_record) + " N²; the "
                  "LIP's data cost, a convex fit, spreads by "
                  f"{np.std(rec.lip_cost_per_record, ddof=1):.3g} N² over the same records: "
                  + ", ".join(f"{c:.5f}" for c in rec.lip_cost_per_record) + " N²). "
                  f"Each record's fit: {st.first.iterations} iterations at most from its "
                  f"draw, then up to {ws.polish} more where it had not converged. Profiles "
                  f"from the best fit on seed {rec.seeds[0]} ({st.first.data_cost:.5f} "
                  f"N² after {st.first.iterations} iterations, {st.first.stop}; "
                  f"{st.data_cost:.5f} N² after {st.iterations} more, {st.stop}); each "
                  f"point ≤ {ws.max_iter} iterations warm-started from its neighbour, ≤ "
                  f"{ws.points} points per direction, {ws.refine} bisections where a "
                  "profile rises.", "",
                  "| parameter | θ* (best fit) | range within δ | ends (down / up) | points "
                  "converged / resolved / neither | monotone (down / up) | LIP ± 95 % "
                  "Newey-West | LIP sd over records |", "|---|---|---|---|---|---|---|---|"]
        for name, e in rec.parameters.items():
            rel, res, neither = _counts(e.points)
            lines.append(
                f"| {name} [{THETA_UNITS[name]}] | {_g(e.start)} | {_range_text(e)} | "
                f"{e.ends.down} / {e.ends.up} | {rel} / {res} / {neither} | "
                f"{'yes' if e.monotone.down else 'no'} / {'yes' if e.monotone.up else 'no'} | "
                f"{_g(li.theta[name])} ± {_g(1.96 * li.std_newey_west[name])} | "
                f"{_g(rec.lip_std[name])} |")
        pts = rec.points
        stops = [p.stop for p in pts]
        rel, res, neither = _counts(pts)
        pred = [p.predicted_decrease for p in pts if p.predicted_decrease is not None]
        rest = [p.tail for p in pts if not p.settled]
        lines += ["", f"Profile points (the start counted once per parameter): {len(pts)}; "
                  f"{rel} pass the optimizer's relative test (Gauss-Newton predicted "
                  f"relative decrease ≤ ftol = {ws.ftol:g}), {res} more pass the "
                  f"resolution test only (predicted absolute decrease, and the fall over the "
                  f"last {ident.TAIL} iterations, ≤ {ws.resolution:g} δ = {ws.atol:.2g} N²), "
                  f"{neither} pass neither (upper bounds on the "
                  "profile there). Stops: " + ", ".join(
                      f"{stops.count(x)} {x}" for x in sorted(set(stops))) + ". Predicted "
                  f"decrease over the points: {min(pred) / rec.delta:.2g} δ to "
                  f"{max(pred) / rec.delta:.2g} δ (median "
                  f"{float(np.median(pred)) / rec.delta:.2g} δ)"
                  + (f"; the largest fall of an unsettled point's data cost over its last "
                     f"{ident.TAIL} iterations {max(rest):.2g} N² "
                     f"({max(rest) / rec.delta:.2g} δ)" if rest else "")
                  + ". Ends: rises = the profile rose above δ; bound = flat to the search "
                  f"bound ({ws.span:g} scales beyond θ* and θ_LIP).", ""]
        confirmed = [p for p in pts if p.confirmed_from is not None]
        if confirmed:
            level = rec.best_data_cost + rec.delta
            fell = [p for p in confirmed if p.data_cost <= level]
            lines += [f"Points that rose above δ, continued for up to {ws.check_iter} more "
                      f"iterations before the rise counted: {len(confirmed)}; "
                      + ", ".join(f"{(p.confirmed_from - rec.best_data_cost) / rec.delta:.2g} δ"
                                  f" → {(p.data_cost - rec.best_data_cost) / rec.delta:.2g} δ"
                                  for p in confirmed)
                      + f" above the best ({len(fell)} fell back within δ).", ""]
        if rec.checks:
            moved = [c.moved for c in rec.checks]
            lines += [f"The resolution test, checked: the {len(moved)} resolved points with the "
                      f"largest predicted decrease, each continued for up to {ws.check_iter} "
                      "more iterations, fell by "
                      + ", ".join(f"{m / rec.delta:.2g} δ" for m in moved)
                      + " (predicted: " + ", ".join(
                          f"{c.predicted_decrease / rec.delta:.2g} δ" for c in rec.checks)
                      + f"); the stated resolution is {ws.resolution:g} δ: "
                      + ("held" if max(moved) <= ws.atol else "NOT held") + ".", ""]
        at = ("" if li.autocorr_at_lags is None
              else f", {li.autocorr_at_lags:.2f} at lag {li.lags}")
        lines += [f"LIP residual autocorrelation {li.lag1_autocorr:.2f} at lag 1{at} "
                  f"({li.lags} Newey-West lags, the automatic bandwidth of Newey and West "
                  f"1994; {li.n_samples} samples).", "",
                  "Sloppy directions of each record's fit (Gauss-Newton matrix J'J of the "
                  "data cost over every parameter, each scaled so that one unit moves the force "
                  "by 1 N rms; an eigenvalue is the cost rise in N² of a unit step): the "
                  "smallest eigenvalue, its ratio to the largest and its share on the network; "
                  "then the θ direction least determined once the network has absorbed what it "
                  "can (smallest eigenvalue of the Schur complement of the network block) and "
                  "that eigenvalue:", "",
                  "| seed | data cost [N²] | stop | λ_min [N²] | λ_min/λ_max | network share "
                  "| least determined θ direction (m, fv, fc, fk) | its eigenvalue [N²] |",
                  "|---|---|---|---|---|---|---|---|"]
        for f in rec.record_fits:
            s, th = f.sloppy.smallest[0], f.sloppy.theta[0]
            lines.append(f"| {f.seed} | {f.data_cost:.5f} | {f.stop} | "
                         f"{s.eigenvalue:.2g} | {s.relative:.2g} | {s.network_share:.3f} | "
                         + ", ".join(f"{th.direction[n]:+.2f}" for n in THETA_NAMES)
                         + f" | {th.eigenvalue:.2g} |")
        lines.append("")
    return "\n".join(lines)

"""The failure map's ``report.md``: the map per case, direction and network size, the verdicts
with Holm's correction beside them, the mechanism and the fits' stops."""

from __future__ import annotations

from clm_sim.plant import THETA_NAMES, THETA_UNITS
from experiments.stats.paired import LogRatio
from experiments.studies.failure_map.result import CellStats, FailureMapResult
from experiments.studies.failure_map.settings import FailureMapSettings


def _um(x: float) -> str:
    return f"{x * 1e6:.3f}"


def _ci(r: LogRatio) -> str:
    return f"{r.ratio:.2f} [{r.low:.2f}, {r.high:.2f}]"


def _why(s: FailureMapResult, c: CellStats) -> str:
    """One generated sentence on the mechanism of a cell: the drift, the network beyond the
    range and the model's force error there."""
    d = s.drift[(c.case, c.hidden)].theta.unregularized
    top = sorted(THETA_NAMES, key=lambda k: -d[k].edge_force_n)[:2]
    drift = ", ".join(f"{k} {d[k].mean:+.3g} {THETA_UNITS[k]} (±"
                      f"{d[k].std:.2g}; {d[k].edge_force_n:.2f} N at the "
                      f"edge of the range)" for k in top)
    n0, n1 = c.network.unregularized, c.network.regularized
    text = f"λ = 0 drifts {drift}"
    if n0.network_peak_beyond_n is not None:
        text += (f"; beyond the range its network outputs up to {n0.network_peak_beyond_n:.2f}"
                 f" N against {n1.network_peak_beyond_n:.2f} N, and the model misses the true"
                 f" force there by {n0.error_beyond_rms_n:.2f} N rms against "
                 f"{n1.error_beyond_rms_n:.2f} N (LIP {c.lip_error_beyond_rms_n:.2f} N)")
    return text


def report(s: FailureMapResult, settings: FailureMapSettings | None = None) -> str:
    """``report.md``: every sentence and number generated from the map."""
    st = s.settings
    lam = st.lam
    outside, inside = s.outside, s.inside
    lines = [f"# Where does λ = 0 fail? MAE(λ = 0) / MAE(λ = {lam:g}) outside the training range",
             "",
             f"Cases (parasitic force of the plant): {', '.join(st.cases)}; directions: "
             + ", ".join(f"{d} ({r})" for d, r in st.outside.items())
             + f"; training reference {st.inside}; n_l ∈ {{{', '.join(map(str, st.hidden))}}}"
             f"; {st.seeds} seeds per cell. Interval: {s.interval}. "
             f"Wall time {s.wall_time_s:.0f} s on {s.workers} workers; code "
             f"{s.code_version or '?'}.", ""]
    n_fits = len(s.fits)
    stops = ", ".join(f"{n} {k}" for k, n in s.fit_stops.items())
    lines += [f"**Fits:** {n_fits} ({stops}). "
              + (f"**{s.unconverged_fits} fits did not pass the convergence test**, "
                 f"{s.capped_fits} of them stopped at the iteration cap (max_iter "
                 f"{st.pgnn.max_iter}); the cells that contain them are marked † below "
                 f"(the count per cell is in failure_map.json)."
                 if s.unconverged_fits else "Every fit passed the convergence test.")]
    if s.failures:
        lines += ["", f"**{len(s.failures)} cells failed** and are left out: "
                  + "; ".join(f"{f.case} n_l={f.hidden} seed {f.seed}: {f.error}"
                              for f in s.failures)]
    lines += ["", "## Where finding (iii) holds (generated from this run)", ""]
    lines += [_region_sentence(s, outside)]
    holds = [c for c in outside if c.verdict == "holds"]
    for c in holds:
        m = c.mae_mean
        lines.append(f"- **{c.label}**: ratio {_ci(c.ratio)} (λ = 0 {_um(m.unregularized)}"
                     f" µm, λ = {lam:g} {_um(m.regularized)} µm, LIP "
                     f"{_um(c.mae_lip_mean)} µm; Holm p = {c.p_holm:.2g}). "
                     f"{_why(s, c)}.")
    rev = [c for c in outside if c.verdict == "reversed"]
    for c in rev:
        lines.append(f"- reversed, **{c.label}**: ratio {_ci(c.ratio)}. {_why(s, c)}.")
    m = s.mechanism
    if m.spearman is not None:
        lines += ["", (f"Across the {m.n_cells} extrapolation cells the MAE ratio follows the "
                  f"ratio of the model's force error beyond the training range (λ = 0 over "
                  f"λ = {lam:g}): Spearman ρ = {m.spearman:.2f}.")]
    lines += ["", "## Extrapolation cells", "",
              (f"MAE mean over seeds [µm]; ratio MAE(λ = 0)/MAE(λ = {lam:g}) with its interval; "
              f"difference λ = 0 minus λ = {lam:g} [µm] with its interval; network peak beyond "
              f"the range [N] (λ = 0 / λ = {lam:g})."), "",
              "| direction | case | n_l | LIP | λ = 0 | λ = " + f"{lam:g}"
              + " | ratio [CI] | difference [CI] | Holm p | verdict | network beyond [N] |",
              "|---|---|---|---|---|---|---|---|---|---|---|"]
    for c in outside:
        d = c.difference_m
        n0, n1 = c.network.unregularized.network_peak_beyond_n, \
            c.network.regularized.network_peak_beyond_n
        m = c.mae_mean
        dag = f" †{c.unconverged_fits}" if c.unconverged_fits else ""
        lines.append(
            f"| {c.direction} ({c.reference}) | {c.case}{dag} | {c.hidden} | "
            f"{_um(c.mae_lip_mean)} | {_um(m.unregularized)} | "
            f"{_um(m.regularized)} | {_ci(c.ratio)} | {d.mean * 1e6:+.3f} "
            f"[{d.low * 1e6:+.3f}, {d.high * 1e6:+.3f}] | {c.p_holm:.2g} | "
            f"{c.verdict}{'' if c.holm_significant or c.verdict == 'undecided' else ' (not after Holm)'} | "
            + (f"{n0:.2f} / {n1:.2f} |" if n0 is not None else "– |"))
    lines += ["", f"## Inside the training range ({st.inside}), for context", "",
              "| case | n_l | LIP | λ = 0 | λ = " + f"{lam:g} | ratio [CI] |", "|---|---|---|---|---|---|"]
    for c in inside:
        m = c.mae_mean
        lines.append(f"| {c.case} | {c.hidden} | {_um(c.mae_lip_mean)} | "
                     f"{_um(m.unregularized)} | {_um(m.regularized)} | "
                     f"{_ci(c.ratio)} |")
    lines += ["", "## Which parameters drift", "",
              ("θ_phy − θ_LIP, mean ± std over seeds (the force it moves at the edge of the training"
              " range in brackets, N)."), "",
              "| case | n_l | λ | " + " | ".join(f"{k} [{THETA_UNITS[k]}]" for k in THETA_NAMES) + " |",
              "|---|---|---|" + "---|" * len(THETA_NAMES)]
    for (case, hidden), d in s.drift.items():
        for theta, lv in ((d.theta.unregularized, "0"), (d.theta.regularized, f"{lam:g}")):
            lines.append(f"| {case} | {hidden} | {lv} | " + " | ".join(
                f"{theta[k].mean:+.3g} ± {theta[k].std:.2g} ({theta[k].edge_force_n:.2f})"
                for k in THETA_NAMES) + " |")
    lines += ["", "## Figures", "",
              "The ratio with its interval per case and n_l, one panel per direction:", "",
              "![ratio](figures/ratio.png)", "",
              ("Mechanism: the MAE ratio against the ratio of the model's force error beyond the "
              "training range:"), "", "![mechanism](figures/mechanism.png)", "",
              "Parameter drift of λ = 0 as the force it moves at the edge of the training range:",
              "", "![drift](figures/drift.png)", ""]
    return "\n".join(lines)


def _region_sentence(s: FailureMapResult, outside: list[CellStats]) -> str:
    lam = s.settings.lam
    n = len(outside)
    holds = [c for c in outside if c.verdict == "holds"]
    rev = [c for c in outside if c.verdict == "reversed"]
    strict = [c for c in holds if c.holm_significant]
    if not holds:
        head = (f"**Finding (iii) holds in none of the {n} extrapolation cells**: no interval of "
                f"MAE(λ = 0)/MAE(λ = {lam:g}) lies above 1.")
    else:
        head = (f"**Finding (iii) holds in {len(holds)} of {n} extrapolation cells** (interval "
                f"above 1; {len(strict)} of them also after Holm's correction): "
                + "; ".join(f"{c.label} {_ci(c.ratio)}" for c in holds) + ".")
    per_dir = []
    for direction in s.settings.outside:
        cs = [c for c in outside if c.direction == direction]
        k = sum(c.verdict == "holds" for c in cs)
        ratios = [c.ratio.ratio for c in cs]
        if not cs:
            per_dir.append(f"{direction}: no cell computed")
            continue
        per_dir.append(f"{direction}: {k} of {len(cs)} cells, ratios "
                       f"{min(ratios):.2f}–{max(ratios):.2f}")
    tail = f" By direction: {'; '.join(per_dir)}."
    if rev:
        tail += (f" Reversed (λ = 0 better, interval below 1) in {len(rev)}: "
                 + "; ".join(c.label for c in rev) + ".")
    return head + tail

"""The mechanism study's ``report.md``: finding (iii) per case, then the mechanism's tables."""

from __future__ import annotations

from clm_sim.plant import THETA_UNITS
from experiments.studies.mechanism.result import MechanismResult
from experiments.studies.mechanism.settings import MechanismSettings


def _p(p) -> str:
    return "–" if p is None else f"{p:.2g}"


def zero_label(settings: MechanismSettings) -> str:
    """How the report names the lambda = 0 row: "λ = 0", or with the parameters that
    ``lambda0_diag`` holds, "λ = 0, stiffness held"."""
    diag = settings.zero_lam_diag or {}
    held = [k for k, v in diag.items() if v > 0]
    return "λ = 0" + (f", {' and '.join(held)} held" if held else "")


def report(s: MechanismResult, settings=None) -> str:
    """The study's Markdown report: finding (iii) per case, then the mechanism table."""
    st = s.settings
    z = zero_label(st)
    diag = st.zero_lam_diag

    def row_label(name: str) -> str:  # summary's "lambda=0.01" as the report names it
        return z if name == "lambda=0" else name.replace("lambda=", "λ = ")

    out = [f"# Finding (iii) over training records, and its mechanism", "",
           f"Per case: {st.records} training records (dither seeds) x {st.draws} network "
           f"draws, n_l = {st.hidden}; {z} and λ = {st.lam:g} on one cost "
           f"(weight decay {st.pgnn.weight_decay:g}, continuation "
           f"{st.pgnn.continuation_lam:g}), paired by record and draw. "
           + ("" if not diag else
              f"The row {z} is λ = 0 with the pull toward θ_LIP on "
              + ", ".join(f"{k} {v:g}" for k, v in diag.items())
              + " only (lambda0_diag): the other parameters are free. ")
           + f"Intervals: "
           f"{100 * st.confidence:g} % two-level bootstrap (records, then draws within "
           f"them; {st.bootstrap} resamples). p: t-test on the per-record means, Holm over "
           f"the cases.", "",
           f"| case | MAE {st.outside}: λ = {st.lam:g} − {z} [µm] | ratio λ = "
           f"{st.lam:g} / {z} | per-record means [µm] | pairs with λ = {st.lam:g} "
           f"lower | p (Holm) | static force error beyond the range, λ = {st.lam:g} − {z} "
           f"[N]: median (pairs with λ = {st.lam:g} higher); mean [interval] | "
           f"Spearman(MAE {st.outside}, force error) |",
           "|---|---|---|---|---|---|---|---|"]
    for case, c in s.cases.items():
        d, r, e = c.mae_outside_diff, c.mae_outside_ratio, c.error_beyond_diff
        out.append(f"| {case} | {d.mean * 1e6:+.3f} [{d.ci[0] * 1e6:+.3f}, "
                   f"{d.ci[1] * 1e6:+.3f}] | {r.ratio:.3f} [{r.ci[0]:.3f}, "
                   f"{r.ci[1]:.3f}] | "
                   + ", ".join(f"{x * 1e6:+.3f}" for x in d.per_record)
                   + f" | {d.lam_lower}/{d.n} | {_p(d.p_records_t)} "
                   f"({_p(d.p_holm)}) | {e.median:+.2f} ({e.higher}/{e.n}); "
                   f"mean {e.mean:+.2f} [{e.ci[0]:+.2f}, {e.ci[1]:+.2f}] | "
                   f"{c.spearman_mae_vs_force_error:.2f} |")
    t_cis = [(case, c.mae_outside_diff.ci_records_t) for case, c in s.cases.items()]
    if all(ci is not None for _, ci in t_cis):
        out += ["", f"The same difference's {100 * st.confidence:g} % t-interval on the "
                f"per-record means (the p column's test; with {st.records} records the "
                "bootstrap's percentile interval is the narrower of the two): "
                + "; ".join(f"{case} [{ci[0] * 1e6:+.3f}, {ci[1] * 1e6:+.3f}] µm"
                            for case, ci in t_cis) + "."]
    out += ["", "Largest static force error beyond the range, per case (the fit that a mean "
            "of the column above can rest on): "
            + "; ".join(f"{case}: record {w.record}, draw {w.draw}, λ = {w.lam:g}, "
                        f"{w.rms_n:.4g} N rms (below the range {w.sides_rms_n[0]:.4g}, "
                        f"above it {w.sides_rms_n[1]:.4g}), MAE {st.outside} "
                        f"{w.mae_outside_um:.3f} µm, force error along {st.outside} "
                        f"beyond the range {w.error_along_rms_n:.3g} N"
                        for case, c in s.cases.items()
                        for w in [c.worst_error_beyond]) + "."]
    out += ["", "**The mechanism** (medians over every fit of the case; static force at rest, "
            "v = a = 0, against position; 'beyond': positions outside the training range out "
            f"to the reach of {st.outside}; Δfk: θ's stiffness minus the LIP's; network "
            "slope: the stiffness column of the network's best linear-in-features part on the "
            "training data; cubic: y³ coefficient of a cubic fitted over the training range, "
            "of the network's remainder (what the drift builds) and of the whole model):", "",
            "| case | row | MAE r1 [µm] | MAE r2 [µm] | force error beyond, rms [N] | force at "
            "the far dwell [N] | Δfk [N/m] | network slope [N/m] | Δfk + slope [N/m] | "
            "remainder cubic [N/m³] | model cubic [N/m³] | converged |",
            "|---|---|---|---|---|---|---|---|---|---|---|---|"]
    for case, c in s.cases.items():
        lip = c.lip
        out.append(f"| {case} | true plant | – | – | – | {c.truth_dwell_force_n:.2f} | – | – "
                   f"| – | – | {c.truth_cubic:.0f} | – |")
        out.append(f"| {case} | LIP | {lip.mae_inside_um:.3f} | {lip.mae_outside_um:.3f} "
                   f"| {lip.error_beyond_rms_n:.2f} | – | 0 | – | – | – | 0 | – |")
        for name, row in c.rows.items():
            out.append(
                f"| {case} | {row_label(name)} | "
                f"{row.mae_inside_um:.3f} | "
                f"{row.mae_outside_um:.3f} | {row.error_beyond_rms_n:.2f} | "
                f"{row.dwell_force_n:.2f} | {row.drift_stiffness:+.4g} | "
                f"{row.network_linear_stiffness:+.4g} | "
                f"{row.model_linear_stiffness_minus_lip:+.3g} | "
                f"{row.remainder_cubic:.0f} | {row.model_cubic:.0f} | "
                f"{row.converged}/{row.fits} |")
    out += ["", f"**The force along {st.outside} beyond the range** (medians; rms over the "
            f"samples of {st.outside} with |r| beyond the training range, of the "
            "feedforward minus the motor command the reference's exact motion needs, "
            "accelerations included; the static curve above holds v = a = 0):", "",
            "| case | rms of the needed command [N] | LIP error [N] | "
            + " | ".join(f"{row_label(n)} error [N]"
                         for n in next(iter(s.cases.values())).rows) + " |",
            "|---|---|---|" + "---|" * len(next(iter(s.cases.values())).rows)]
    for case, c in s.cases.items():
        lip = c.lip
        out.append(f"| {case} | {lip.need_along_rms_n:.2f} | {lip.error_along_rms_n:.2f} | "
                   + " | ".join(f"{row.error_along_rms_n:.2f}" for row in c.rows.values())
                   + " |")
    moved = [(case, name, row.theta_moved) for case, c in s.cases.items()
             for name, row in c.rows.items()]
    if moved:
        out += ["", "How far θ_phy travelled (median over the fits of |θ − θ_LIP|; "
                + ", ".join(f"{k} {u}" for k, u in THETA_UNITS.items()) + "): "
                + "; ".join(f"{case}, {row_label(name)}: "
                            + ", ".join(f"{k} {v:.3g}" for k, v in m.items())
                            for case, name, m in moved) + "."]
    if all(c.effects_beyond for c in s.cases.values()):
        out += ["", "**Per effect, the force the LIP's columns do not hold** (rms of the effect's "
                "force along the exact motion minus its least-squares projection on a, v, "
                f"sign v, y, 1 over {st.inside}; on {st.inside}, and along "
                f"{st.outside} beyond the range):", "",
                f"| case | effect | on {st.inside} [N] | along {st.outside} beyond [N] |",
                "|---|---|---|---|"]
        for case, c in s.cases.items():
            for name, e in c.effects_beyond.items():
                out.append(f"| {case} | {name.split(':', 1)[1]} | {e.inside_rms_n:.3f} | "
                           f"{e.beyond_rms_n:.3f} |")
    if any(c.units is not None for c in s.cases.values()):
        out += ["", f"**Unit by unit** (medians over the fits; a unit is named near-linear when "
                f"its pre-activation stays within ±{st.near_linear:g} on every training "
                "sample; share: the named units' part of the squared remainder force beyond the "
                "range; intervention: the named units' tanh replaced by their line over the "
                "training samples; control: as many unnamed units, those with the most remainder "
                "force on the training samples; Δ: error beyond, arm minus the fit itself, "
                "median over the fits that have named units):", "",
                "| case | row | named units (range) | fits with named | share beyond | static "
                "error beyond: fit / named / control [N] | Δ named / Δ control [N] | named "
                "lowers it more | static error inside: fit / named / control [N] | MAE "
                f"{st.outside}: fit / named / control [µm] |",
                "|---|---|---|---|---|---|---|---|---|---|"]
        f3 = lambda x, p=".2f": "–" if x is None else format(x, p)  # noqa: E731
        for case, c in s.cases.items():
            for name, u in (c.units or {}).items():
                out.append(
                    f"| {case} | {row_label(name)} | {u.named_median:g} "
                    f"({u.named_range[0]}–{u.named_range[1]}) | "
                    f"{u.fits_with_named}/{u.fits} | {u.named_share_beyond:.2f} | "
                    f"{f3(u.error_beyond_none_n)} / {f3(u.error_beyond_named_n)} / "
                    f"{f3(u.error_beyond_control_n)} | {f3(u.delta_beyond_named_n, '+.2f')}"
                    f" / {f3(u.delta_beyond_control_n, '+.2f')} | "
                    f"{u.named_lowers_more}/{u.fits_with_named} | "
                    f"{f3(u.error_inside_none_n, '.3f')} / "
                    f"{f3(u.error_inside_named_n, '.3f')} / "
                    f"{f3(u.error_inside_control_n, '.3f')} | "
                    f"{f3(u.mae_outside_none_um, '.3f')} / "
                    f"{f3(u.mae_outside_named_um, '.3f')} / "
                    f"{f3(u.mae_outside_control_um, '.3f')} |")
    for case, c in s.cases.items():
        pr = c.prediction
        if pr is None:
            continue
        yes = lambda b: "held" if b else "did not hold"  # noqa: E731
        out += ["", f"**The prediction written before the run ({case})**: MAE {st.outside}, "
                f"λ = {st.lam:g} − {z}: {pr.mae_diff_um:+.3f} µm"
                + (f" (calibrated on the cubic cable: {pr.mae_diff_calibrated_um:+.3f} µm)"
                   if pr.mae_diff_calibrated_um is not None else "")
                + f"; static force error beyond the range: {z} {pr.error_beyond_lambda0_n:.2f}"
                f" N, λ = {st.lam:g} {pr.error_beyond_lambda_n:.2f} N; an amount holds "
                f"within a factor {pr.factor:g}. Measured: {pr.measured_mae_diff_um:+.3f}"
                f" µm (t-interval on the per-record means [{pr.measured_ci_um[0]:+.3f}, "
                f"{pr.measured_ci_um[1]:+.3f}]); errors beyond (medians) "
                f"{pr.measured_error_beyond_lambda0_n:.2f} N and "
                f"{pr.measured_error_beyond_lambda_n:.2f} N. The sign {yes(pr.sign_held)}; "
                f"the amount {yes(pr.amount_held)}"
                + (f"; the calibrated amount {yes(pr.calibrated_amount_held)}"
                   if pr.calibrated_amount_held is not None else "")
                + f"; {z}'s force error beyond {yes(pr.error_beyond_lambda0_held)}; "
                f"λ = {st.lam:g}'s {yes(pr.error_beyond_lambda_held)}."]
    out += ["", "Figure: `figures/force_beyond.png` (first record, draw 0 of each case)."]
    return "\n".join(out) + "\n"

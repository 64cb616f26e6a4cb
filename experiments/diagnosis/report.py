"""Write a diagnosis into a folder, atomically: ``diagnosis.json``, ``report.md``, figures."""

from __future__ import annotations

import json
from pathlib import Path

from clm_sim.outdir import atomic_folder
from experiments.diagnosis.diagnose import Diagnosis


def _figures(d: Diagnosis, folder: Path) -> list[tuple[str, str]]:
    from experiments import plots  # matplotlib is loaded only when a report is written
    from experiments.diagnosis.figures import diagnosis_figures

    shown = []
    for name, (fig, caption) in diagnosis_figures(d).items():
        plots.save(fig, folder / name)
        shown.append((name, caption))
    return shown


def _fmt(value) -> str:
    if isinstance(value, dict):
        return ", ".join(f"{k} {_fmt(v)}" for k, v in value.items())
    if isinstance(value, float):
        return f"{value:.4g}"
    if isinstance(value, (list, tuple)):
        return "[" + ", ".join(_fmt(v) for v in value) + "]"
    return str(value)


def markdown(d: Diagnosis, figures: list[tuple[str, str]]) -> str:
    g, rec = d.gain, d.info.record
    p = d.model.plant
    effects = "; ".join(f"{e.type} ({_fmt(e.parameters())})" for e in p.effects) or "none"
    ctrl = "given (the loop is re-simulated)" if d.model.controller is not None else "not given"
    lines = [f"# Diagnosis of model '{d.model.name}' against {rec.source}", "",
             f"**Model used:** '{d.model.name}': mass {p.mass:.4g} kg, viscous {p.viscous:.4g} "
             f"N·s/m, coulomb {p.coulomb:.4g} N, stiffness {p.stiffness:.4g} N/m; effects: "
             f"{effects}; controller {ctrl}.",
             "",
             f"{rec.samples} samples at {1 / rec.sample_time_s:g} Hz; encoder step "
             f"{rec.encoder_quantum_m:.3g} m; fitted where the position path tells the "
             f"direction of motion (four same-way steps around the sample, at least "
             f"{rec.speed_floor_m_s:.3g} m/s); parallel low-pass "
             f"{rec.regression_lowpass_hz:.4g} Hz "
             f"(the encoder's quantization alone makes {rec.quantization_floor_n:.3g} N "
             f"there). "
             f"Residual RMS {rec.residual_rms_n:.4g} N.", "", "## Findings", ""]
    lines += ["```", d.summary(), "```"]
    rule = d.info.significance_rule
    lines += ["", f"Significance rule: {rule.cv}; a candidate is accepted when it lowers the "
              f"held-out MSE by at least {100 * rule.min_gain:g} % (and by "
              f"{100 * rule.min_explained:g} % of the model's own residual), in at least "
              f"{rule.min_folds} of the folds, with an F-test p < {rule.p_value:g}, and "
              f"is admissible to its family (physical bounds, the family's law checked on the "
              f"data); between two explanations that fit about equally the one with fewer "
              f"parameters is named (docs/diagnosis.md). Explained fraction: held-out MSE drop "
              f"when the cause joined, over the model's. Unexplained: a part of the residual "
              f"that passes the significance rule but that no family may name.",
              "", "## Out-of-sample gain", "", f"Validation: {d.info.validation}.", "",
              "| quantity | before | after |", "|---|---|---|",
              f"| force residual RMS (N) | {g.residual_rms_before:.4g} | "
              f"{g.residual_rms_after:.4g} |",
              f"| the encoder's quantization floor (N), no model goes below | "
              f"{g.quantization_floor_n:.3g} | |"]
    if g.simulation_rmse_before is not None:
        lines.append(f"| open-loop simulation from the input, position RMSE (mm; initial state "
                     f"from the first {g.simulation_init_samples} positions) | "
                     f"{g.simulation_rmse_before * 1e3:.4g} | "
                     f"{g.simulation_rmse_after * 1e3:.4g} |")
    if g.lip_residual_rms_before is not None:
        lines.append(f"| LIP re-identified, residual RMS (N) | {g.lip_residual_rms_before:.4g} "
                     f"| {g.lip_residual_rms_after:.4g} |")
    if g.resim_mismatch_rms_before is not None:
        lines.append(f"| re-simulated minus measured tracking error, RMS (µm) | "
                     f"{g.resim_mismatch_rms_before * 1e6:.4g} | "
                     f"{g.resim_mismatch_rms_after * 1e6:.4g} |")
        lines.append(f"\nMeasured tracking error RMS {g.tracking_rms_measured * 1e6:.4g} µm.")
    if g.origin is not None:
        o = g.origin
        lines += ["", "### Encoder origin of the validation record", "",
                  "An incremental encoder is zeroed where the axis was homed, so a periodic force "
                  "can sit at another measured position in another experiment. The validation "
                  f"record's origin is registered on the {o.registered_on}: shift "
                  f"{o.shift_m * 1e3:+.4g} mm (modulo {o.period_m * 1e3:.4g} mm, the period "
                  f"of the strongest periodic effect). On the remaining {o.samples} samples:",
                  "", "| quantity | before | after, fixed origin | after, registered |",
                  "|---|---|---|---|",
                  f"| force residual RMS (N) | {o.residual_rms_before:.4g} | "
                  f"{o.residual_rms_after_fixed_origin:.4g} | {o.residual_rms_after:.4g} |"]
        if o.resim_mismatch_rms_before is not None:
            lines.append(f"| re-simulated minus measured tracking error, RMS (µm) | "
                         f"{o.resim_mismatch_rms_before * 1e6:.4g} | "
                         f"{o.resim_mismatch_rms_after_fixed_origin * 1e6:.4g} | "
                         f"{o.resim_mismatch_rms_after * 1e6:.4g} |")
    elif g.origin_error is not None:
        lines += ["", f"The validation record's encoder origin could not be registered: "
                  f"{g.origin_error}"]
    ff = d.info.feedforward_gain
    if ff is not None:
        lines += ["", "## LIP feedforward on the emulated machine", "",
                  "Tracking MAE (µm), replayed on the truth plant; LIP extended with "
                  + (", ".join(e["type"] for e in ff.lip_effects) or "no effect") + ".", "",
                  "| reference | before | after |", "|---|---|---|"]
        lines += [f"| {ref} | {v['before'] * 1e6:.4g} | {v['after'] * 1e6:.4g} |"
                  for ref, v in ff.lip_mae_m.items()]
    lines += ["", "## Figures", ""]
    lines += [f"![{cap}](figures/{name})\n\n{cap}.\n" for name, cap in figures]
    return "\n".join(lines) + "\n"


def write(d: Diagnosis, out: Path) -> None:
    """Write ``diagnosis.json``, ``report.md`` and ``figures/`` into ``out`` (replaced as a
    whole; an interrupted write leaves nothing behind)."""
    with atomic_folder(out, what="a diagnosis") as tmp:
        shown = _figures(d, tmp / "figures")
        (tmp / "diagnosis.json").write_text(json.dumps(d.to_json(), indent=1))
        (tmp / "report.md").write_text(markdown(d, shown))

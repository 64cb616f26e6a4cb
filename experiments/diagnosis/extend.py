"""Extend the model with the named causes and measure the gain out of sample.

The accepted terms are fitted jointly on the estimation record; parameter corrections go into the
plant's ``mass, viscous, coulomb, stiffness`` and the effects are appended to ``plant.effects``, so
the simulator and the LIP (``LIPFeedforward(effects=...)``) are extended with the same objects.
"""

from __future__ import annotations

import dataclasses

import numpy as np

from experiments.diagnosis.families import REGISTRY
from experiments.diagnosis.finding import Finding
from experiments.diagnosis.fitting import coefficient_std, cv_of, fit_cv
from experiments.diagnosis.origin import registered_gain
from experiments.diagnosis.outcome import Gain, GainSignals
from experiments.diagnosis.residual import DiagnosisSettings, Residual
from experiments.model_files import Controller
from clm_sim.effects.base import Effect
from clm_sim.effects.friction import Stribeck
from clm_sim.errors import UserError
from clm_sim.features import FeatureMap, edge_force
from clm_sim.loop import simulate
from clm_sim.open_loop import INIT_SAMPLES, initial_state, score, simulate_input
from clm_sim.plant import THETA_NAMES, Plant
from clm_sim.run import Run
from controllers.lip import LIPFeedforward


def joint_fit(res: Residual, steps) -> tuple[list[Finding], dict, tuple[Effect, ...]]:
    """Fit all accepted terms together; returns ``(findings, theta_correction, effects)``: the
    findings ordered by their explained fraction, the effects ranked like them. Each family makes
    its own finding and correction (:meth:`Family.finding`)."""
    st = res.settings
    if not steps:
        return [], {}, ()
    x = np.column_stack([s.cols for s in steps])
    full = fit_cv(x, res.z, res.fold, st.folds)
    # Explained fraction: the held-out MSE drop when the term joined (in selection order), over
    # the held-out MSE of the model's residual; the fractions add up to the total explained.
    # ``unique_fraction``: the rise when it alone is left out of the final model.
    cv = [cv_of(res, *[s.cols for s in steps[:j]]).cv_mse for j in range(len(steps) + 1)]
    base = cv[0]
    std = coefficient_std(res, x, full.coef)
    findings, correction = [], {}
    start = 0
    for i, step in enumerate(steps):
        k = step.cols.shape[1]
        coef = {key: float(c) for key, c in zip(step.term.keys, full.coef[start:start + k])}
        sd = {key: float(c) for key, c in zip(step.term.keys, std[start:start + k])}
        unique = (cv_of(res, *[s.cols for j, s in enumerate(steps) if j != i]).cv_mse
                  - full.cv_mse) / base
        stats = {"explained_fraction": float((cv[i] - cv[i + 1]) / base),
                 "unique_fraction": float(unique), "selection_gain": float(step.gain),
                 "folds_improved": int(step.folds_improved), "p_value": float(step.p_value)}
        findings.append(REGISTRY[step.term.effect].finding(res, step.term, coef, sd, step.cols,
                                                           stats, correction))
        start += k
    ranked = sorted(findings, key=lambda f: -f.explained_fraction)
    effects = tuple(f.effect_object for f in ranked if f.effect_object is not None)
    return ranked, correction, effects


def extended_plant(plant: Plant, correction: dict, effects: tuple[Effect, ...]) -> Plant:
    """The model with the corrections and the found effects (physical bounds kept); model
    effects the data does not support (``correction["drop"]``) are left out."""
    theta = {k: float(getattr(plant, k)) + correction.get(k, 0.0) for k in THETA_NAMES}
    drop = correction.get("drop", [])
    kept = tuple(e for e in plant.effects if not any(e is d for d in drop))
    theta["mass"] = max(theta["mass"], 1e-3 * plant.mass)
    theta["viscous"] = max(theta["viscous"], 0.0)
    theta["coulomb"] = max(theta["coulomb"], 0.0)
    # A friction dip takes at most the Coulomb friction (the joint fit may ask a little more).
    room, bounded = theta["coulomb"], []
    for e in kept + tuple(effects):
        if isinstance(e, Stribeck) and e.peak < 0:
            e = dataclasses.replace(e, peak=max(e.peak, -room))
        room += e.peak if isinstance(e, Stribeck) else 0.0
        bounded.append(e)
    return dataclasses.replace(plant, **theta, effects=tuple(bounded))


def lip_effects(effects) -> tuple[Effect, ...]:
    """The effects a LIP takes: one per type (its regressor names are per type), the first of
    each in ``effects`` (ranked: the strongest)."""
    seen: dict[str, Effect] = {}
    for e in effects:
        seen.setdefault(e.type, e)
    return tuple(seen.values())


def fit_lip(features: FeatureMap, effects, run: Run) -> LIPFeedforward:
    """A LIP with ``lip_effects(effects)`` fitted on ``run``. Where the record has too few
    standstill samples to tell a constant force from the Coulomb part of a friction asymmetry
    (collinear columns), the asymmetry's ``|sign v|`` column carries the constant and the
    ``force_offset`` is left out."""
    effects = lip_effects(effects)
    try:
        return LIPFeedforward(features=features, effects=effects).fit(y=run.y, u=run.u, ts=run.ts)
    except UserError:
        types = {e.type for e in effects}
        if not {"force_offset", "friction_asymmetry"} <= types:
            raise
        effects = tuple(e for e in effects if e.type != "force_offset")
        return LIPFeedforward(features=features, effects=effects).fit(y=run.y, u=run.u, ts=run.ts)


def lip_residual_rms(est: Run, val: Residual, val_run: Run, effects, cutoff: float) -> float:
    """Out-of-sample force RMS (N) of a LIP with ``effects`` fitted on ``est``, on ``val``."""
    lip = fit_lip(FeatureMap(regression_lowpass_hz=cutoff), effects, est)
    pred = lip.predict(y=val_run.y, ts=val_run.ts, u=val_run.u)
    z = val.filter(edge_force(val_run.u) - pred)[val.idx]
    return float(np.sqrt(np.mean(z**2)))


def resimulate(plant: Plant, controller: Controller, run: Run) -> np.ndarray:
    """Tracking error (m) of the loop re-simulated on the measured reference, with the measured
    external input (``u`` minus the feedback's share) injected."""
    ext = controller.external_input(run.r, run.y, run.u)
    sim = simulate(plant, controller, run.r, run.ts, u_ff=ext + controller.reference_force(run.r))
    return sim.e


def simulation_rmse(plant: Plant, run: Run, init_samples: int = INIT_SAMPLES) -> float:
    """RMSE (m) of ``plant`` simulated open loop from ``run.u``, its initial state from the
    first ``init_samples`` of ``run.y`` (the benchmark protocol), over the samples after them."""
    state = initial_state(run.y, run.ts, plant, init_samples)
    x, _ = simulate_input(plant, run.u, run.ts, state)
    return score(run.y, x, init_samples).rmse


def gains(est: Run, val: Run, settings: DiagnosisSettings, before: Plant, after: Plant,
          effects: tuple[Effect, ...], controller: Controller | None, *,
          val_offset: int | None = None, full: Run | None = None) -> tuple[Gain, GainSignals]:
    """Out-of-sample gain numbers and the signals the report draws.

    ``val_offset``: where ``val`` starts inside ``full`` when it is the held-out tail of one
    record (then the loop is re-simulated over ``full`` and compared on the tail).
    """
    res_b, res_a = Residual(val, before, settings), Residual(val, after, settings)
    gain = {"residual_rms_before": res_b.rms(), "residual_rms_after": res_a.rms(),
            "validation_samples": len(val), "fitted_validation_samples": int(len(res_b.idx))}
    gain["residual_rms_reduction"] = 1.0 - gain["residual_rms_after"] / \
        max(gain["residual_rms_before"], 1e-300)
    gain["quantization_floor_n"] = res_b.quantization_floor()
    try:
        gain["lip_effects"] = tuple(e.type for e in lip_effects(effects))
        lip = (lip_residual_rms(est, res_b, val, (), res_b.cutoff),
               lip_residual_rms(est, res_b, val, effects, res_b.cutoff))
        gain["lip_residual_rms_before"], gain["lip_residual_rms_after"] = lip
    except UserError as exc:  # a LIP cannot always take every effect (collinear columns)
        gain["lip_error"] = str(exc)
    try:  # what the simulation gets wrong, before and after: the field's score
        gain["simulation_rmse_before"] = simulation_rmse(before, val)
        gain["simulation_rmse_after"] = simulation_rmse(after, val)
        gain["simulation_init_samples"] = INIT_SAMPLES
    except UserError as exc:
        gain["simulation_error"] = str(exc)
    signals = {"val_before": res_b, "val_after": res_a}
    if val_offset is None:  # another experiment: its encoder origin may differ
        try:
            origin = registered_gain(
                val, before, after, settings,
                None if controller is None else lambda p, r: resimulate(p, controller, r))
        except UserError as exc:
            gain["origin_error"] = str(exc)
        else:
            if origin is not None:
                gain["origin"], signals["origin_scan"] = origin
    if controller is not None:
        run, cut = (full, val_offset) if val_offset is not None else (val, 0)
        try:
            e_b = resimulate(before, controller, run)[cut:]
            e_a = resimulate(after, controller, run)[cut:]
        except UserError as exc:
            gain["resimulation_error"] = str(exc)
        else:
            e_m = run.e[cut:]
            gain["tracking_rms_measured"] = float(np.sqrt(np.mean(e_m**2)))
            gain["resim_mismatch_rms_before"] = float(np.sqrt(np.mean((e_b - e_m) ** 2)))
            gain["resim_mismatch_rms_after"] = float(np.sqrt(np.mean((e_a - e_m) ** 2)))
            signals.update(t=run.t[cut:], e_measured=e_m, e_before=e_b, e_after=e_a)
    return Gain(**gain), GainSignals(**signals)

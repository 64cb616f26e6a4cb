"""Warnings where the data look wrong but may be right: each is one line for stderr, and the
command still runs (a refusal is for what cannot be right: :mod:`clm_sim.records.checks`).

- ``y`` leads ``r``: a measured position follows its reference, so the columns may be swapped;
- the force does not push the position as a force should (a fitted mass below zero, by more than
  its standard error): ``u`` may have the wrong sign or belong to another axis;
- a model's mass far from the mass the record's own force and acceleration give: ``u`` may be in
  volts (a forgotten ``--scale``), or the model's mass in g;
- a plant mass outside what linear-motor carriages weigh.
"""

from __future__ import annotations

import sys

import numpy as np

MASS_RANGE_KG = (0.01, 1000.0)  # from a 10 g voice-coil stage to a 1 t gantry
MASS_RATIO = 3.0  # model and data masses this far apart (either way) mean units, not a mismatch
MIN_LEAD_SAMPLES = 2  # a lead of one sample is rounding of a delay-free feedforward
MAX_LAG_S = 0.05  # s: tracking delays of a servo are shorter


def lead_samples(r: np.ndarray, y: np.ndarray, ts: float) -> int:
    """Samples by which ``y`` leads ``r`` (negative: lags), from the peak of the
    cross-correlation of their increments within ``MAX_LAG_S``; 0 without clear motion."""
    dr, dy = np.diff(r), np.diff(y)
    if not (np.any(dr) and np.any(dy)):
        return 0
    n = len(dr)
    max_lag = int(min(n // 4, max(1, MAX_LAG_S / ts)))
    size = 1 << int(np.ceil(np.log2(2 * n)))
    xc = np.fft.irfft(np.fft.rfft(dy, size) * np.conj(np.fft.rfft(dr, size)), size)
    lags = np.r_[0:max_lag + 1, -max_lag:0]
    values = np.r_[xc[:max_lag + 1], xc[-max_lag:]]
    best = int(lags[np.argmax(values)])  # xc[k]: dy[i + k] against dr[i]; k < 0: y leads
    peak = values.max() / (np.linalg.norm(dr) * np.linalg.norm(dy))
    return -best if peak > 0.5 else 0


def record_warnings(run, lip, *, model_mass: float | None = None) -> list[str]:
    """The warnings about a record ``run`` (``lip``: a LIP fitted to it, or None)."""
    out = []
    lead = lead_samples(run.r, run.y, run.ts)
    if lead >= MIN_LEAD_SAMPLES:
        out.append(f"y leads r by {lead} samples ({lead * run.ts * 1e3:.3g} ms), but a measured "
                   f"position follows its reference: are the y and r columns swapped?")
    if lip is None:
        return out
    mass, std = lip.theta_["mass"], lip.std_["mass"]
    if mass < -3 * std:
        out.append(f"u does not push y as a force should: the fitted mass is {mass:.4g} kg "
                   f"(< 0); is u's sign, or its column, right?")
    elif model_mass is not None and mass > 0 and not (
            1 / MASS_RATIO <= mass / model_mass <= MASS_RATIO):
        out.append(f"the model's mass {model_mass:.4g} kg is far from the record's "
                   f"{mass:.4g} kg (force over acceleration): is u in N (a forgotten --scale "
                   f"u=...), and the model's mass in kg?")
    return out


def plant_warnings(plant, where: str) -> list[str]:
    """The warnings about a plant's parameters (``where``: the config's name for it)."""
    lo, hi = MASS_RANGE_KG
    if not lo <= plant.mass <= hi:
        return [f"{where}.mass: {plant.mass:g} kg is outside {lo:g}..{hi:g} kg of linear-motor "
                f"carriages; is it in kg?"]
    return []


def config_warnings(config) -> list[str]:
    """The warnings about an experiment config's plants (``plant``, ``truth``)."""
    return [line for where, plant in (("plant", config.plant), ("truth", config.truth))
            if plant is not None for line in plant_warnings(plant, where)]


def warn(path, lines: list[str]) -> None:
    """Data that look wrong but may be right: one stderr line each; the command goes on."""
    sys.stderr.write("".join(f"clm-sim: warning: {path}: {line}\n" for line in lines))

"""The guards of every identification from a measured record (``identify``, ``diagnose``,
``run`` with a ``data:`` section): one set, so that no command gives a confident number from data
that cannot carry it.

- :func:`refuse_unidentifiable`: a record that identifies nothing (no force, a constant force,
  no motion, too few samples in the training window) is refused in one line;
- :func:`refuse_other_rate`: a validation record at another sample rate, likewise;
- :func:`fit_warnings`: a result that may be wrong is said in one line each: a filter cut-off near
  the Nyquist frequency or below what the record can resolve, a position quantized so coarsely
  that its acceleration is noisy enough to bias the mass low (errors in the regressor: measured
  on a smooth copy of the record quantized alike), a mass that moves when the regression band
  is halved (noise of another origin: sampling jitter behind uniform time stamps), a mass no
  linear motor has or that the record leaves undetermined, a model whose force on the record's
  reference is far beyond the record's force;
- :func:`simulated_fit_checks`: the same guards on a LIP fitted to a simulated closed-loop run
  (``run`` without ``data:``, the studies, the sweeps), where ``u`` is the loop's force on ``y``
  by construction: a fit that is not physical there (a mass not above zero, a force far beyond
  the run's, non-finite numbers, too few samples) is refused, the rest warned.
"""

from __future__ import annotations

import numpy as np

from clm_sim.errors import UserError
from experiments.records.suspicions import MASS_RANGE_KG

MIN_FIT_SAMPLES = 200  # samples a fit of 4 parameters needs at least (as a record: MIN_SAMPLES)
NYQUIST_FRACTION = 0.8  # a cut-off above this fraction of Nyquist: the filter is not a filter
MIN_CUTOFF_PERIODS = 5.0  # a cut-off whose period fits fewer times in the record: transient only
MIN_CUTOFF_HZ = 1.0  # Hz: servo forces change faster; below, the filter leaves only drift
QUANTIZATION_BIAS = 0.05  # an estimated quantization bias of the mass above this is said
BAND_CHANGE = 0.05  # a mass that moves by more than this when the band is halved is said
UNDETERMINED = 0.5  # a mass whose standard error exceeds this fraction of it is not identified
FORCE_RATIO = 10.0  # a model force on the reference this many times the record's peak is absurd
FORCE_QUANTILE = 99.0  # % of the model's force on r compared (a step in r is one spike, not a fit)


def refuse_unidentifiable(run, source) -> None:
    """Raise ``UserError`` (one line naming ``source``) where the record ``run`` carries no
    parameter at all: ``u`` zero or constant, ``y`` constant or taking two values only."""
    u, y = run.u, run.y
    if np.ptp(y) == 0:
        raise UserError(f"{source}: y is constant ({y[0]:.6g} m in every sample): too little "
                        f"excitation; a record without motion does not excite any parameter")
    if not np.any(u):
        raise UserError(f"{source}: u is zero in every sample; a record without force "
                        f"identifies nothing (is the u column, or its --scale, right?)")
    if np.ptp(u) <= 1e-12 * float(np.max(np.abs(u))):
        raise UserError(f"{source}: u is constant ({u[0]:.6g} N in every sample); a constant "
                        f"force cannot tell mass from friction (is the u column right?)")
    if len(np.unique(y[:100_000])) < 3 and len(np.unique(y)) < 3:
        raise UserError(f"{source}: y takes only two values; its quantization is coarser than "
                        f"the motion (is y the position in m?)")


def refuse_other_rate(validation, run, source) -> None:
    """Raise ``UserError`` (one line naming ``source``) where the ``validation`` record is
    sampled at another rate than the record ``run`` it checks: the same filters and differences
    at another rate score another quantity."""
    if abs(validation.ts / run.ts - 1) > 1e-3:
        raise UserError(f"{source}: sampled at {validation.ts:g} s, the record at {run.ts:g} s; "
                        f"a validation record needs the same rate")


def refuse_small_window(count: int, total: int, source: str,
                        fix: str = "widen data.window") -> None:
    """Raise ``UserError`` where a training window keeps fewer than ``MIN_FIT_SAMPLES``."""
    if count < MIN_FIT_SAMPLES:
        raise UserError(f"{source}: the training window keeps {count} of {total} samples; a "
                        f"fit needs at least {MIN_FIT_SAMPLES} ({fix})")


def reference_force(theta: dict, run) -> tuple[float, float] | None:
    """``(model, record)``: the rigid-body force of ``theta`` on the record's reference ``r``
    (its ``FORCE_QUANTILE`` percentile of ``|force|``, N) and the record's peak ``|u|`` (N);
    ``None`` where ``r`` does not move or ``u`` is zero (nothing to compare)."""
    from clm_sim.features import motion
    from clm_sim.rigid_body import rigid_body

    r, u = np.asarray(run.r, dtype=np.float64), np.asarray(run.u, dtype=np.float64)
    data = float(np.max(np.abs(u))) if len(u) else 0.0
    if len(r) < 3 or not np.ptp(r) > 0 or not data > 0:
        return None
    y, v, a = motion(r, run.ts)
    with np.errstate(over="ignore", invalid="ignore"):
        force = np.abs(rigid_body(theta, a, v, np.sign(v), y))
    model = float(np.percentile(force, FORCE_QUANTILE)) if np.all(np.isfinite(force)) \
        else float("inf")
    return model, data


def force_line(theta: dict, run) -> str | None:
    """The line that says a model's force on the record's reference is far beyond the record's
    own force (``FORCE_RATIO``), else ``None``."""
    forces = reference_force(theta, run)
    if forces is None or forces[0] <= FORCE_RATIO * forces[1]:
        return None
    shown = ", ".join(f"{k} {v:.4g}" for k, v in theta.items())
    return (f"the identified model asks {forces[0]:.3g} N to follow the record's reference r, "
            f"{forces[0] / forces[1]:.3g} times the record's peak force {forces[1]:.3g} N: the "
            f"parameters are not the machine's ({shown})")


def simulated_fit_checks(run, features, theta: dict, std: dict, *, machine_mass: float,
                         samples: int) -> list[str]:
    """The guards of a LIP ``theta`` (standard errors ``std``) fitted through ``features`` on
    ``samples`` samples of the simulated closed-loop run ``run`` of a machine of mass
    ``machine_mass`` kg. Refuses (``UserError``, naming the config key) a fit with too few
    samples, non-finite numbers, a mass not above zero or a force far beyond the run's: the
    loop's ``u`` is the force on ``y``, so such a fit says the data do not carry the parameters
    (a filter that leaves no signal). Returns the warnings (cut-off, a mass far from the
    machine's, undetermined)."""
    from experiments.records.suspicions import MASS_RATIO

    key = "features.regression_lowpass_hz"
    cutoff = features.regression_lowpass_hz
    refuse_small_window(samples, len(run), "training run",
                        "a longer training reference or fewer features.edge_samples")
    values = [*theta.values(), *std.values()]
    band = f" at {key} {cutoff:g} Hz" if cutoff else ""
    if not all(np.isfinite(values)):
        raise UserError(f"training run: the LIP fit gives non-finite parameters{band}; the run "
                        f"does not carry them (a filter that leaves no signal?)")
    mass = theta["mass"]
    if not mass > 0:
        raise UserError(f"training run: the LIP fit gives a mass of {mass:.4g} kg{band} (the "
                        f"machine's is {machine_mass:g} kg): the filtered run carries no "
                        f"inertia; " + (cutoff_warnings(cutoff, run.ts, len(run), key) or
                                        [f"check {key} and the training reference"])[0])
    line = force_line(theta, run)
    if line is not None:
        raise UserError(f"training run: {line}{band}; " + (
            cutoff_warnings(cutoff, run.ts, len(run), key) or [f"check {key}"])[0])
    out = fit_warnings(run, features, theta, std, option=key)
    if not 1 / MASS_RATIO <= mass / machine_mass <= MASS_RATIO:
        out.append(f"the identified mass {mass:.4g} kg is far from the simulated machine's "
                   f"{machine_mass:g} kg: the fit{band} does not recover the plant (is {key} "
                   f"right?)")
    return out


def quantization_step(y: np.ndarray) -> float:
    """The step (m) in which ``y`` moves: its smallest non-zero increment (0 for a record
    that moves in steps below float rounding)."""
    steps = np.abs(np.diff(y))
    steps = steps[steps > 1e-12 * max(float(np.max(np.abs(y))), 1e-300)]
    return float(steps.min()) if len(steps) else 0.0


def quantization_bias(y: np.ndarray, ts: float, cutoff: float | None, refit) -> float:
    """The fraction by which quantization of ``y`` (its :func:`quantization_step`) biases the
    least-squares mass low: the mass ``refit`` gives on a smooth copy of ``y`` (zero-phase
    Butterworth at half the regression ``cutoff``, Hz; 0.05/ts without one) against the mass on
    that copy quantized to the same step. Quantization noise in the second-difference
    acceleration is noise in the regressor, which shrinks the mass (errors in variables); the
    copy carries the record's motion without the noise. On EMPS quantized to 1, 3 and 10 um it
    gives 12, 44 and 95 % for 13, 47 and 96 %; on the simulated record at 5 um 52 % for 55 %."""
    import scipy.signal

    q = quantization_step(y)
    if q == 0:
        return 0.0
    band = 0.5 * min(cutoff or 0.1 / ts, 0.2 / ts)
    sos = scipy.signal.butter(4, band, fs=1.0 / ts, output="sos")
    smooth = scipy.signal.sosfiltfilt(sos, y)
    clean = refit(smooth, cutoff)
    if not clean > 0:
        return 0.0
    noisy = refit(np.round(smooth / q) * q, cutoff)
    return float(np.clip(1 - noisy / clean, 0.0, 1.0)) if np.isfinite(noisy) else 0.0


def cutoff_warnings(cutoff: float | None, ts: float, samples: int, option: str) -> list[str]:
    """A regression cut-off (Hz) near the Nyquist frequency, or too low for the record."""
    if cutoff is None:
        return []
    nyquist, duration = 0.5 / ts, samples * ts
    if cutoff > NYQUIST_FRACTION * nyquist:
        return [f"{option} {cutoff:g} Hz is {cutoff / nyquist:.0%} of the record's Nyquist "
                f"frequency {nyquist:g} Hz: the second-difference acceleration is not filtered "
                f"there; give a lower {option} (e.g. {0.2 / ts:g} Hz)"]
    low = max(MIN_CUTOFF_HZ, MIN_CUTOFF_PERIODS / duration)
    if cutoff < low:
        return [f"{option} {cutoff:g} Hz is below {low:.3g} Hz: the filter passes only drift "
                f"and its own transient in a {duration:.3g} s record; is it in Hz?"]
    return []


def fit_warnings(run, features, theta: dict, std: dict | None, option: str,
                 refit=None) -> list[str]:
    """The warnings about parameters ``theta`` (``std``: their standard errors, or None)
    identified from ``run`` through ``features`` (``option``: the cut-off's name in the
    command's input; ``refit(y, cutoff)``: the mass the same fit gives on positions ``y`` with
    the regression cut-off ``cutoff`` Hz, for the quantization and bandwidth checks)."""
    cutoff = features.regression_lowpass_hz
    out = cutoff_warnings(cutoff, run.ts, len(run), option)
    mass = theta.get("mass", float("nan"))
    if refit is not None:
        bias = quantization_bias(run.y, run.ts, cutoff, refit)
        if bias > QUANTIZATION_BIAS:
            out.append(f"y moves in steps of {quantization_step(run.y):.3g} m: quantization noise "
                       f"in the acceleration biases the mass low, by about {bias:.0%} (errors "
                       f"in the regressor; a smooth copy of y quantized alike loses as much); "
                       f"give a lower {option} or a finer position")
        elif mass > 0:
            half = 0.5 * (cutoff or 0.5 / run.ts)
            narrow = refit(run.y, half)
            if narrow > 0 and abs(narrow - mass) > BAND_CHANGE * narrow:
                band = f"{cutoff:g} Hz" if cutoff else "no filter"
                out.append(f"the mass is {mass:.4g} kg at {option} {band} but "
                           f"{narrow:.4g} kg at {half:g} Hz: noise in the acceleration (sampling "
                           f"jitter, quantization, an unmodelled resonance) biases it in the "
                           f"wider band; give a lower {option}")
    lo, hi = MASS_RANGE_KG
    error = (std or {}).get("mass", 0.0)
    if not mass > 0 and not mass < -3 * error:
        # below zero by more than 3 standard errors is suspicions.record_warnings's line (u's
        # sign); nearer zero, or not a number, it is this one: either way never silent
        out.append(f"the identified mass {mass:.4g} kg (standard error {error:.2g} kg) is not "
                   f"a physical mass: the record does not determine it (a glitch in y, too "
                   f"little excitation) or u is not the force on y; a feedforward from it is "
                   f"wrong")
    elif mass > 0 and not lo <= mass <= hi:
        out.append(f"the identified mass {mass:.4g} kg is outside {lo:g}..{hi:g} kg of "
                   f"linear-motor carriages: are u in N and y in m?")
    if std is not None and mass > 0 and std.get("mass", 0.0) > UNDETERMINED * mass:
        out.append(f"the mass {mass:.4g} kg has a standard error of {std['mass']:.2g} kg: "
                   f"the record does not determine it (more excitation, a longer record)")
    if all(k in theta for k in ("mass", "viscous", "coulomb", "stiffness")):
        line = force_line(theta, run)
        if line is not None:
            out.append(line)
    return out

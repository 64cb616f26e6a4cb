"""Linear-in-the-parameters (LIP) inverse-dynamics feedforward, identified by least squares.

``u = m*a + fv*v + fc*sign(v) + fk*y`` (+ the regressors of any named effects whose nonlinear
parameters are fixed, e.g. a cogging period). Closed-form least squares on the aligned, filtered
features of :class:`clm_sim.features.FeatureMap`.
"""

from __future__ import annotations

import json
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from clm_sim.effects.base import Effect
from clm_sim.errors import NotFittedError, UserError, check_ts
from clm_sim.features import FeatureMap, edge_force, held_force, lip_regressors
from clm_sim.modelfile import mapping, number, read_json, sample_time
from clm_sim.numerics import single_threaded
from clm_sim.outdir import atomic_write
from clm_sim.plant import THETA_NAMES
from clm_sim.rigid_body import rigid_body
from clm_sim.schema import build, build_effect


FEATURE_KEYS = ("regression_lowpass_hz", "position_lowpass_hz", "lowpass_order", "edge_samples")


def _effect_columns(effects, y, v, u) -> dict[str, np.ndarray]:
    cols: dict[str, np.ndarray] = {}
    for effect in effects:
        for name, col in effect.regressors(y, v, u).items():
            if name in cols:
                raise UserError(f"lip: two effects contribute the same regressor {name!r}")
            cols[name] = col
    return cols


@dataclass
class LIPFeedforward:
    """The linear-in-the-parameters (LIP) inverse-dynamics feedforward.

    ``u = m a + fv v + fc sign(v) + fk y`` (+ the regressors of named effects), identified by
    least squares from a logged run. As scikit-learn's estimators: the constructor stores
    settings, ``fit(*, y, u, ts)`` learns and returns the model; ``predict`` and
    ``feedforward`` use it at the fitted sample time only; ``save``/``load`` keep it as JSON.

    Parameters
    ----------
    features : FeatureMap
        The preprocessing (filter, alignment).
    effects : tuple of Effect
        Extra named effects whose linear coefficients are identified alongside ``theta``
        (their nonlinear parameters, e.g. a cogging period, stay fixed).

    Attributes
    ----------
    theta_ : dict
        ``mass`` (kg), ``viscous`` (N*s/m), ``coulomb`` (N), ``stiffness`` (N/m).
    std_ : dict
        Standard errors of every coefficient (white-noise least squares).
    effects_ : tuple of Effect
        The effects with their identified coefficients.
    ts_ : float
        Sample time (s) of the data the model was fitted on.

    Raises
    ------
    UserError
        From ``fit``: a record that does not excite every parameter (it needs motion in both
        directions); from ``predict``/``feedforward``: another sample time than the fitted.
    NotFittedError
        ``predict``, ``feedforward`` or ``save`` before ``fit``.

    Examples
    --------
    >>> from clm_sim import ExperimentConfig, Plant, PointToPoint, Testbed, Training
    >>> back_and_forth = PointToPoint(points_m=(0.0, 0.02, -0.02, 0.0), dwell_s=0.1)
    >>> config = ExperimentConfig(plant=Plant(effects=()), references={"r": back_and_forth},
    ...                           training=Training(reference="r", repeats=1), replay=("r",))
    >>> run = Testbed(config).training_run(seed=1)   # 2 s in closed loop, 50 N dither
    >>> from clm_sim import LIPFeedforward
    >>> lip = LIPFeedforward().fit(y=run.y, u=run.u, ts=run.ts)
    >>> round(lip.theta_["mass"], 1), lip.ts_                 # kg (the plant's: 18.8), s
    (18.8, 0.0001)
    >>> u_ff = lip.feedforward(back_and_forth.sample(1e-4).r)  # N per sample, for a replay
    >>> lip.save("lip.json"); LIPFeedforward.load("lip.json").theta_ == lip.theta_
    True
    """

    features: FeatureMap = field(default_factory=FeatureMap)
    effects: tuple[Effect, ...] = ()

    def _design(self, y, v, a, u):
        cols = _effect_columns(self.effects, y, v, u)
        return np.column_stack([lip_regressors(y, v, a), *cols.values()]), list(cols)

    def fit(self, *, y: np.ndarray, u: np.ndarray, ts: float) -> "LIPFeedforward":
        """Identify from measured positions ``y`` (m) and applied forces ``u`` (N), with one
        BLAS thread (:func:`clm_sim.numerics.single_threaded`): OpenBLAS splits the sums of a
        long record's normal matrix over its threads, so ``std_`` (and on the EMPS record
        ``theta_``) moved in the last digits with the machine's cores."""
        with single_threaded():
            return self._fit(y, u, ts)

    def _fit(self, y: np.ndarray, u: np.ndarray, ts: float) -> "LIPFeedforward":
        yf, v, a = self.features.motion(y, ts)
        ue = edge_force(u)
        phi, extra = self._design(yf, v, a, ue)
        keep = self.features.fit_slice(len(yf))
        phi = self.features.regression_filter(phi, ts)[keep]
        target = self.features.regression_filter(ue, ts)[keep]
        scale = np.linalg.norm(phi, axis=0)
        if np.any(scale == 0) or np.linalg.matrix_rank(phi / scale) < phi.shape[1]:
            raise UserError("lip: the record does not excite all parameters (a regressor is "
                            "zero or collinear); it needs motion in both directions")
        coef, *_ = np.linalg.lstsq(phi / scale, target, rcond=None)
        coef = coef / scale
        resid = target - phi @ coef
        dof = max(len(target) - len(coef), 1)
        cov = np.linalg.pinv(phi.T @ phi) * (resid @ resid / dof)
        names = list(THETA_NAMES) + extra
        self.theta_ = {n: float(c) for n, c in zip(THETA_NAMES, coef)}
        self.coef_ = {n: float(c) for n, c in zip(names, coef)}
        self.std_ = {n: float(s) for n, s in zip(names, np.sqrt(np.clip(np.diag(cov), 0, None)))}
        self.effects_ = tuple(e.from_coefficients(self.coef_) for e in self.effects)
        self.residual_rms_ = float(np.sqrt(np.mean(resid**2)))
        self.ts_ = float(ts)
        return self

    def _check_fitted(self):
        if not hasattr(self, "theta_"):
            raise NotFittedError("LIPFeedforward is not fitted: call fit() before predict(), "
                                 "feedforward() or save()")

    def _rate(self, ts: float | None) -> float:
        """``ts`` checked against the fitted sample time (default: that one)."""
        own = getattr(self, "ts_", None)
        if ts is None:
            if own is None:
                raise UserError("LIPFeedforward: give ts (this model does not know its rate)")
            return own
        check_ts(own, ts, "LIPFeedforward (fitted)")
        return float(ts)

    def predict(self, *, y: np.ndarray, ts: float | None = None,
                u: np.ndarray | None = None) -> np.ndarray:
        """Force (N) at the sample instants for positions ``y`` sampled at ``ts`` (s; default and
        only allowed rate: the fitted ``ts_``); ``u`` feeds force-ripple terms."""
        self._check_fitted()
        ts = self._rate(ts)
        yf, v, a = self.features.motion(y, ts)
        th = self.theta_
        out = rigid_body(th, a, v, np.sign(v), yf)
        if self.effects_:
            base = out if u is None else edge_force(u)
            for e in self.effects_:
                out = out + e.force(yf, v, base)
        return out

    def feedforward(self, r: np.ndarray, ts: float | None = None) -> np.ndarray:
        """The held input (N) per sample that tracks reference ``r`` (m) sampled at ``ts`` (s;
        default and only allowed rate: the fitted ``ts_``)."""
        return held_force(self.predict(y=r, ts=ts))

    def to_json(self) -> dict:
        """The fitted model as plain data (``kind: lip``; what :meth:`save` writes)."""
        self._check_fitted()
        return {"kind": "lip", **self.theta_, "ts": getattr(self, "ts_", None),
                "std": self.std_, "coefficients": self.coef_,
                "residual_rms_n": self.residual_rms_,
                "effects": [e.as_config() for e in self.effects_],
                "features": {k: getattr(self.features, k) for k in FEATURE_KEYS}}

    def save(self, path) -> None:
        """Write the fitted model to the JSON file ``path`` (theta, ts, effects, features)."""
        atomic_write(Path(path), json.dumps(self.to_json(), indent=1))

    @classmethod
    def load(cls, path) -> LIPFeedforward:
        """Read a model written by :meth:`save` (or by ``clm-sim identify`` and ``clm-sim run``;
        a file without ``ts`` or ``features`` gives a model that needs ``ts`` at every use and
        the default features)."""
        path = Path(path)
        info = read_json(path, "LIP model")
        try:
            if info.get("kind") != "lip":
                raise UserError(f"kind: expected \"lip\", got {json.dumps(info.get('kind'))}")
            if not isinstance(info.get("effects") or [], list):
                raise UserError("effects: expected a list")
            effects = tuple(build_effect(e, f"effects[{i}]")
                            for i, e in enumerate(info.get("effects") or []))
            features = build(FeatureMap, mapping(info.get("features"), "features"), "features")
            model = cls(features=features, effects=effects)
            model.theta_ = {k: number(info.get(k), k) for k in THETA_NAMES}
            model.coef_ = {k: number(v, f"coefficients.{k}") for k, v in
                           mapping(info.get("coefficients", model.theta_), "coefficients").items()}
            model.std_ = {k: number(v, f"std.{k}") for k, v in
                          mapping(info.get("std"), "std").items()}
            rms = info.get("residual_rms_n")
            model.residual_rms_ = float("nan") if rms is None else number(rms, "residual_rms_n")
            ts = sample_time(info.get("ts"))
        except UserError as exc:
            raise UserError(f"{path}: cannot read a LIP model ({exc})") from None
        model.effects_ = effects
        if ts is not None:
            model.ts_ = ts
        return model

    @classmethod
    def fitted(cls, *, theta: dict[str, float], effects: tuple[Effect, ...] = (),
               features: FeatureMap | None = None, ts: float | None = None) -> "LIPFeedforward":
        """A LIP with given parameters (a file's ``theta`` in SI units and fitted ``effects``),
        usable for ``predict`` and ``feedforward`` as if fitted; no fit statistics."""
        missing = [k for k in THETA_NAMES if k not in theta]
        if missing:
            raise UserError(f"lip: parameters missing: {', '.join(missing)}")
        lip = cls(features=features or FeatureMap(), effects=tuple(effects))
        lip.theta_ = {k: number(theta[k], k) for k in THETA_NAMES}  # finite; true is no 1 kg
        lip.effects_ = tuple(effects)
        if ts is not None:
            lip.ts_ = sample_time(ts)
        return lip

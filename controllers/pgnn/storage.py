"""A fitted PGNN on disk: ``path.pt`` (the torch module's tensors, input scalings included) and
``path.json`` (settings as a model file names them, theta, the fit record, the history), and the
checks that refuse a file that is not such a model in one line."""

from __future__ import annotations

import json
from pathlib import Path

import torch

from clm_sim.errors import UserError
from clm_sim.features import FeatureMap
from clm_sim.modelfile import mapping, number, read_json, regular_file, sample_time
from clm_sim.plant import THETA_NAMES
from clm_sim.schema import build
from controllers.pgnn.cost import CostTerms
from controllers.pgnn.fit_record import FitRecord, Iterate
from controllers.pgnn.network import PGNNNetwork
from controllers.pgnn_settings import (CONSTRAINTS, LAMBDA_KEYS, check_settings, checked_widths,
                                       parameter_count)

# A model file's settings keys are the Python names but where it spells lambda out.
FILE_KEYS = {v: k for k, v in LAMBDA_KEYS.items() if v != "lam"}


def file_settings(values: dict) -> dict:
    """A model's settings (``values``: every setting by its Python name, ``hidden`` as a list) as
    a model file names them (lambda spelled out where a file does), in the order of
    ``CONSTRAINTS``."""
    return {FILE_KEYS.get(k, k): values[k] for k in CONSTRAINTS}


def to_json(model) -> dict:
    model._check_fitted()
    return {"kind": "pgnn", "ts": getattr(model, "ts_", None), "settings": model._settings(),
            "features": {k: getattr(model.features, k) for k in (
                "regression_lowpass_hz", "position_lowpass_hz", "lowpass_order",
                "edge_samples")},
            "theta": model.theta_, "theta_lip": model.theta_lip_,
            "cost": None if model.cost_ is None else model.cost_.to_json(),
            "fit": model.fit_.to_json(), "best_iteration": model.best_iteration_,
            "n_samples": model.n_samples_, "history": (None if model.history_ is None
                                                    else [h.to_json() for h in model.history_])}


def save(model, path) -> None:
    """Write ``path.pt`` (the module's state_dict: float64 tensors, input scalings included)
    and ``path.json`` (settings, theta, fit record, history)."""
    model._check_fitted()
    path = Path(path)
    torch.save(model.network_.state_dict(), path.with_suffix(".pt"))
    path.with_suffix(".json").write_text(json.dumps(model.to_json(), indent=1))


def load(cls, path):
    """The model of class ``cls`` written by :func:`save` (tensors loaded with ``weights_only=True``)."""
    path = Path(path)
    info = read_json(path.with_suffix(".json"), "PGNN model")
    pt = regular_file(path.with_suffix(".pt"), "PGNN weights file")
    try:
        python = {v: k for k, v in FILE_KEYS.items()}
        settings = {python.get(k, k): v for k, v in
                    mapping(info.get("settings"), "settings").items()
                    if python.get(k, k) in CONSTRAINTS}
        settings["hidden"] = checked_widths(settings.get("hidden"), "settings.hidden")
        check_settings(settings)
        features = build(FeatureMap, mapping(info.get("features"), "features"), "features")
        theta = mapping(info.get("theta"), "theta")
        theta = {k: number(theta.get(k), f"theta.{k}") for k in THETA_NAMES}
        ts = sample_time(info.get("ts"))
        fit = FitRecord.from_json(info.get("fit"))
        cost = info.get("cost")
        cost = None if cost is None else CostTerms.from_json(cost)
        history = info.get("history")
        if history is not None:
            if not isinstance(history, list):
                raise UserError("history: expected a list")
            history = [Iterate.from_json(e) for e in history]
        # The weights' size follows from the widths: a larger file is not this model's.
        weights = parameter_count(settings["hidden"]) + 8  # + the input scalings
        if pt.stat().st_size > 16 * weights + 2 ** 20:
            raise UserError(f"{pt.name}: {pt.stat().st_size} bytes, far more than the "
                            f"{weights} weights of hidden {list(settings['hidden'])}")
    except UserError as exc:
        raise UserError(f"{path}: cannot read PGNN model ({exc})") from None
    try:
        state = torch.load(pt, weights_only=True)
        model = cls(**settings, features=features)
        net = PGNNNetwork(hidden=model.widths(), activation=model.settings.activation)
        check_shapes(state, net, pt, f"{path.with_suffix('.json').name}'s hidden "
                                      f"{list(model.widths())}")
        net.load_state_dict(state)
    except UserError:
        raise
    except Exception as exc:  # a truncated or foreign .pt, weights of another shape
        first = (str(exc).splitlines() or [type(exc).__name__])[0][:200]
        raise UserError(f"{path}: cannot read PGNN model ({first})") from None
    for name, tensor in net.state_dict().items():
        if not bool(torch.isfinite(tensor).all()):
            raise UserError(f"{pt}: {name} holds NaN or inf; not a usable model")
    if not bool((net.mlp.input_std > 0).all()):
        raise UserError(f"{pt}: mlp.input_std must be positive (a scaling), got "
                        f"{net.mlp.input_std.tolist()}")
    model.network_ = net
    model.theta_ = theta
    model.theta_lip_ = info.get("theta_lip")
    model.history_ = history
    model.best_iteration_ = info.get("best_iteration")
    model.cost_ = cost
    model.fit_ = fit
    model.n_samples_ = info.get("n_samples")
    model.ts_ = ts  # older files: unknown
    return model


def check_shapes(state, net: torch.nn.Module, pt: Path, widths: str) -> None:
    """Refuse in one line a ``.pt`` whose tensors are not those of the network its ``.json``
    describes (``widths``): the first tensor missing, of another shape, or extra, by name,
    expected against found (``load_state_dict`` says it in a paragraph)."""
    if not isinstance(state, dict) or not all(isinstance(v, torch.Tensor)
                                              for v in state.values()):
        return  # load_state_dict says what it is
    for name, tensor in net.state_dict().items():
        shape = tuple(tensor.shape)
        if name not in state:
            raise UserError(f"{pt}: no tensor {name}; {widths} expects one of shape "
                            f"{shape}")
        if tuple(state[name].shape) != shape:
            raise UserError(f"{pt}: {name} has shape {tuple(state[name].shape)}; "
                            f"{widths} expects {shape}")
    extra = [k for k in state if k not in net.state_dict()]
    if extra:
        raise UserError(f"{pt}: {extra[0]} is no tensor of {widths}")

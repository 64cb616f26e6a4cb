"""A PGNN's hidden units one by one, and an intervention on the ones the cubic-continuation
reading names.

For a one-hidden-layer tanh network ``f(phi) = w . tanh(W s(phi) + b) + c`` (``s``: the network's
fixed input scaling), unit ``j``'s **operating range** on a set of inputs is the span of its
pre-activation ``z_j = W_j s(phi) + b_j`` there, and its **linear share** is the R^2 of the least-
squares line of ``tanh(z_j)`` in ``z_j`` over that set (1: the unit acts as a line there).

The reading: a unit run on the near-linear part of its tanh over the training data (``|z_j| <=
near_linear`` on every training sample) carries a cubic as its Taylor remainder, which goes on
growing beyond the data. The **intervention** replaces such a unit's ``tanh(z_j)`` by its line in
``z_j`` fitted over the training samples (its remainder removed, its linear part kept, so the
slope it cancels against theta stays cancelled), and re-measures the model's force beyond the
range. Its **control** does the same to as many units the reading does not name: those whose
remainder carries the most force (rms over the training samples) among the others.
"""

from __future__ import annotations

import numpy as np


def _layer(model):
    mlp = model.network_.mlp
    if len(mlp.hidden) != 1 or mlp.activation != "tanh":
        raise ValueError("units: a network of one tanh hidden layer is expected")
    g = lambda t: t.detach().numpy().astype(float)  # noqa: E731
    return (g(mlp.input_mean), g(mlp.input_std), g(mlp.hidden[0].weight), g(mlp.hidden[0].bias),
            g(mlp.out.weight)[0], float(mlp.out.bias.detach()))


def pre_activations(model, phi: np.ndarray) -> np.ndarray:
    """The hidden pre-activations ``z`` (N, n) at feature columns ``phi`` (N, 4)."""
    mean, std, w, b, _, _ = _layer(model)
    return ((phi - mean) / std) @ w.T + b


def lines(z_train: np.ndarray) -> np.ndarray:
    """Per unit, the least-squares line ``(slope, intercept)`` of ``tanh(z)`` in ``z`` over the
    training pre-activations ``z_train`` (N, n): shape (n, 2)."""
    out = np.empty((z_train.shape[1], 2))
    for j in range(z_train.shape[1]):
        cols = np.column_stack([z_train[:, j], np.ones(len(z_train))])
        out[j] = np.linalg.lstsq(cols, np.tanh(z_train[:, j]), rcond=None)[0]
    return out


def linear_share(z: np.ndarray) -> np.ndarray:
    """Per unit, R^2 of the least-squares line of ``tanh(z)`` in ``z`` over the rows of ``z``."""
    out = np.empty(z.shape[1])
    for j in range(z.shape[1]):
        h = np.tanh(z[:, j])
        cols = np.column_stack([z[:, j], np.ones(len(z))])
        res = h - cols @ np.linalg.lstsq(cols, h, rcond=None)[0]
        var = float(np.sum((h - h.mean()) ** 2))
        out[j] = 1.0 - float(np.sum(res ** 2)) / var if var > 0 else 1.0
    return out


def network_with_lines(model, phi: np.ndarray, units, fitted_lines: np.ndarray) -> np.ndarray:
    """The network's force (N) at ``phi`` with the ``units`` given their training lines in place
    of their tanh."""
    _, _, _, _, w_out, b_out = _layer(model)
    z = pre_activations(model, phi)
    h = np.tanh(z)
    for j in units:
        h[:, j] = fitted_lines[j, 0] * z[:, j] + fitted_lines[j, 1]
    return h @ w_out + b_out


def view(model, phi_train: np.ndarray, phi_beyond: np.ndarray, near_linear: float) -> dict:
    """Per unit: the operating range and linear share on the training samples and on ``phi_beyond``
    (the static curve beyond the range), its output weight, the rms force (N) of its remainder
    (``w_j (tanh z_j - line_j(z_j))``) on each; the units the reading names (``named``: every
    training pre-activation within +-``near_linear``) and the control's (``control``)."""
    _, _, _, _, w_out, _ = _layer(model)
    zt, zb = pre_activations(model, phi_train), pre_activations(model, phi_beyond)
    fl = lines(zt)

    def remainder_rms(z):
        rest = np.tanh(z) - (z * fl[:, 0] + fl[:, 1])
        return np.sqrt(np.mean((rest * w_out) ** 2, axis=0))

    rt, rb = remainder_rms(zt), remainder_rms(zb)
    named = [int(j) for j in np.flatnonzero(np.max(np.abs(zt), axis=0) <= near_linear)]
    others = [j for j in range(zt.shape[1]) if j not in named]
    control = sorted(sorted(others, key=lambda j: -rt[j])[:len(named)])
    return {"named": named, "control": control, "lines": fl.tolist(),
            "units": [{"range_training": [float(zt[:, j].min()), float(zt[:, j].max())],
                       "range_beyond": [float(zb[:, j].min()), float(zb[:, j].max())],
                       "linear_share_training": float(s_t), "linear_share_beyond": float(s_b),
                       "output_weight": float(w_out[j]), "remainder_training_rms_n": float(rt[j]),
                       "remainder_beyond_rms_n": float(rb[j])}
                      for j, s_t, s_b in zip(range(zt.shape[1]), linear_share(zt),
                                             linear_share(zb))]}

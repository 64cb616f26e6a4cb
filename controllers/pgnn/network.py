"""The PGNN as a torch module: ``u = theta_phy . T(phi) + f_NN(z)``, float64.

``T(phi)`` are the physical regressor columns (the LIP features ``[a, v, sign v, y]``); ``f_NN`` is
a multilayer perceptron of any widths (``hidden=(16,)``, ``(32, 32)``) and activation on the
network inputs ``z`` (the same features), normalised by fixed scalings stored as buffers. The last
layer of ``f_NN`` is linear; its weights and bias and ``theta_phy`` enter the output linearly, which
the training (variable projection, :mod:`controllers.pgnn.cost`) exploits. Derivatives come from
``torch.func``, so a new architecture needs no new derivative code.
"""

from __future__ import annotations

import itertools

import numpy as np
import torch
from torch import nn
from torch.func import functional_call, jacrev, vmap

# The one map from an activation name in a config to a module.
ACTIVATIONS = {"tanh": nn.Tanh, "sigmoid": nn.Sigmoid, "softplus": nn.Softplus, "silu": nn.SiLU,
               "gelu": nn.GELU, "relu": nn.ReLU}
DTYPE = torch.float64


class MLP(nn.Module):
    """``f_NN(z)``: scaled inputs ``(z - input_mean) / input_std`` through ``hidden`` layers of
    ``activation`` and one linear output neuron (N, in N). ``last_hidden=True`` returns the last
    hidden layer's outputs (N, hidden[-1]) instead."""

    def __init__(self, n_inputs: int, hidden: tuple[int, ...], activation: str):
        super().__init__()
        self.register_buffer("input_mean", torch.zeros(n_inputs, dtype=DTYPE))
        self.register_buffer("input_std", torch.ones(n_inputs, dtype=DTYPE))
        widths = (n_inputs, *hidden)
        self.hidden = nn.ModuleList(nn.Linear(a, b, dtype=DTYPE)
                                    for a, b in itertools.pairwise(widths))
        self.act = ACTIVATIONS[activation]()
        self.out = nn.Linear(widths[-1], 1, dtype=DTYPE)

    def forward(self, z: torch.Tensor, last_hidden: bool = False) -> torch.Tensor:
        h = (z - self.input_mean) / self.input_std
        for layer in self.hidden:
            h = self.act(layer(h))
        return h if last_hidden else self.out(h).squeeze(-1)


class PGNNNetwork(nn.Module):
    """Physical layer ``theta`` (N per unit of each regressor) in parallel with :class:`MLP`."""

    def __init__(self, n_physical: int = 4, n_inputs: int = 4, hidden=(16,),
                 activation: str = "tanh"):
        super().__init__()
        self.theta = nn.Parameter(torch.zeros(n_physical, dtype=DTYPE))
        self.mlp = MLP(n_inputs, tuple(hidden), activation)

    def forward(self, phi: torch.Tensor, z: torch.Tensor) -> torch.Tensor:
        return phi @ self.theta + self.mlp(z)

    # -- the split used by the training --------------------------------------------------------
    def nonlinear_names(self) -> list[str]:
        """Names (in ``mlp``) of the parameters that enter the output nonlinearly: every
        hidden layer's weights and biases."""
        return [k for k, _ in self.mlp.named_parameters() if not k.startswith("out.")]

    def get_nonlinear(self) -> np.ndarray:
        """The nonlinear parameters as one float64 vector (order of :meth:`nonlinear_names`)."""
        p = dict(self.mlp.named_parameters())
        return np.concatenate([p[k].detach().numpy().ravel() for k in self.nonlinear_names()])

    def set_nonlinear(self, beta: np.ndarray) -> None:
        with torch.no_grad():
            for k, v in self._split(beta).items():
                self.mlp.get_parameter(k).copy_(v)

    def set_linear(self, theta: np.ndarray, w_out: np.ndarray, b_out: float) -> None:
        """Physical parameters and the output layer (the linearly entering parameters)."""
        with torch.no_grad():
            self.theta.copy_(torch.from_numpy(np.asarray(theta, dtype=np.float64)))
            self.mlp.out.weight.copy_(torch.from_numpy(np.asarray(w_out, dtype=np.float64))[None])
            self.mlp.out.bias.fill_(float(b_out))

    def _split(self, beta: np.ndarray) -> dict[str, torch.Tensor]:
        """Named tensors (views) of a flat nonlinear-parameter vector: the one place it is cut."""
        b = torch.from_numpy(np.ascontiguousarray(beta, dtype=np.float64))
        out, i = {}, 0
        for k in self.nonlinear_names():
            shape = self.mlp.get_parameter(k).shape
            n = shape.numel()
            out[k] = b[i:i + n].reshape(shape)
            i += n
        return out

    def hidden_outputs(self, beta: np.ndarray, z: torch.Tensor) -> np.ndarray:
        """Last hidden layer's outputs (N, n) at nonlinear parameters ``beta``."""
        with torch.no_grad():
            h = functional_call(self.mlp, self._split(beta), (z,), {"last_hidden": True},
                                strict=False)
        return h.numpy()

    def network_jacobian(self, beta: np.ndarray, w_out: np.ndarray, z: torch.Tensor) -> np.ndarray:
        """``d f_NN / d beta`` (N, len(beta)) at nonlinear parameters ``beta`` and output weights
        ``w_out`` (the output bias does not depend on beta): per-sample reverse mode, vmapped."""
        mlp = self.mlp
        w = torch.from_numpy(np.ascontiguousarray(w_out, dtype=np.float64))

        def f(params, zi):
            return functional_call(mlp, params, (zi[None],), {"last_hidden": True},
                                   strict=False)[0] @ w

        grads = vmap(jacrev(f), in_dims=(None, 0))(self._split(beta), z)
        return torch.cat([grads[k].reshape(len(z), -1) for k in self.nonlinear_names()],
                         dim=1).numpy()

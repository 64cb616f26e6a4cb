"""The PGNN as a torch module: ``u = theta_phy . T(phi) + f_NN(z)``, float64.

``T(phi)`` are the physical regressor columns (the LIP features ``[a, v, sign v, y]``); ``f_NN`` is
a multilayer perceptron of any widths (``hidden=(16,)``, ``(32, 32)``) and activation on the
network inputs ``z`` (the same features), normalised by fixed scalings stored as buffers. The last
layer of ``f_NN`` is linear; its weights and bias and ``theta_phy`` enter the output linearly, which
the training (variable projection, :mod:`controllers.pgnn.cost`) exploits.

The training's Jacobian ``d f_NN / d beta`` is the closed form of backpropagation for a perceptron
of any depth (:meth:`PGNNNetwork.network_jacobian`): per sample, a layer's weight gradient is the
outer product of its back-propagated sensitivity and its input. It is written once for every width
and depth, with each activation's derivative from :data:`DERIVATIVES` beside :data:`ACTIVATIONS`;
``tests/test_pgnn.py`` checks it against ``torch.func`` and central differences. The per-sample
reverse mode of ``torch.func`` (``vmap(jacrev)``) it replaces cost 9 ms of the 60 ms of an
n_l = 16 training iteration for arithmetic that takes 1 ms (``benchmarks/bench_fit.py``).
"""

from __future__ import annotations

import itertools

import numpy as np
import torch
from torch import nn
from torch.func import functional_call

# The one map from an activation name in a config to a module.
ACTIVATIONS = {"tanh": nn.Tanh, "sigmoid": nn.Sigmoid, "softplus": nn.Softplus, "silu": nn.SiLU,
               "gelu": nn.GELU, "relu": nn.ReLU}
DTYPE = torch.float64


def _sigmoid_derivative(pre, out):
    return out * (1 - out)


def _softplus_derivative(pre, out):
    # nn.Softplus() is linear above its threshold (pre > 20), as its own backward is.
    return torch.where(pre > 20, torch.ones_like(pre), torch.sigmoid(pre))


def _silu_derivative(pre, out):
    s = torch.sigmoid(pre)
    return s * (1 + pre * (1 - s))


def _gelu_derivative(pre, out):
    # nn.GELU() is the exact (erf) form: x Phi(x).
    return (0.5 * (1 + torch.erf(pre * 0.5 ** 0.5))
            + pre * torch.exp(-0.5 * pre * pre) * (2 * torch.pi) ** -0.5)


def _tanh_derivative(pre, out):
    return 1 - out * out


def _relu_derivative(pre, out):
    return (pre > 0).to(DTYPE)


# d act / d pre as a function of the pre-activation and the activation's output, per name.
DERIVATIVES = {"tanh": _tanh_derivative, "sigmoid": _sigmoid_derivative,
               "softplus": _softplus_derivative, "silu": _silu_derivative,
               "gelu": _gelu_derivative, "relu": _relu_derivative}


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
        self.activation = activation
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
        # (name, shape, offset) of each nonlinear parameter in the flat vector beta: the layout
        # is fixed by the architecture, so it is read once, not at every evaluation.
        pieces, i = [], 0
        for k, v in self.mlp.named_parameters():
            if not k.startswith("out."):
                pieces.append((k, v.shape, i))
                i += v.numel()
        self._pieces = tuple(pieces)

    def forward(self, phi: torch.Tensor, z: torch.Tensor) -> torch.Tensor:
        return phi @ self.theta + self.mlp(z)

    # -- the split used by the training --------------------------------------------------------
    def nonlinear_names(self) -> list[str]:
        """Names (in ``mlp``) of the parameters that enter the output nonlinearly: every
        hidden layer's weights and biases."""
        return [k for k, _, _ in self._pieces]

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
        return {k: b[i:i + shape.numel()].view(shape) for k, shape, i in self._pieces}

    def hidden_outputs(self, beta: np.ndarray, z: torch.Tensor) -> np.ndarray:
        """Last hidden layer's outputs (N, n) at nonlinear parameters ``beta``."""
        with torch.no_grad():
            h = functional_call(self.mlp, self._split(beta), (z,), {"last_hidden": True},
                                strict=False)
        return h.numpy()

    def layer_outputs(self, beta: np.ndarray, zs: torch.Tensor
                      ) -> tuple[list[torch.Tensor], list[torch.Tensor]]:
        """Pre-activations and outputs of every hidden layer at nonlinear parameters ``beta`` for
        scaled inputs ``zs = (z - input_mean) / input_std`` (each a list, first layer first)."""
        params = self._split(beta)
        pres, outs, h = [], [], zs
        with torch.no_grad():
            for i, layer in enumerate(self.mlp.hidden):
                pre = torch.nn.functional.linear(h, params[f"hidden.{i}.weight"],
                                                 params[f"hidden.{i}.bias"])
                h = self.mlp.act(pre)
                pres.append(pre)
                outs.append(h)
        return pres, outs

    def network_jacobian(self, beta: np.ndarray, w_out: np.ndarray, zs: torch.Tensor,
                         layers=None, out: np.ndarray | None = None) -> np.ndarray:
        """``d f_NN / d beta`` (N, len(beta)) at nonlinear parameters ``beta`` and output weights
        ``w_out`` (the output bias does not depend on beta), for scaled inputs ``zs`` (see
        :meth:`layer_outputs`, whose result ``layers`` may be passed to skip the forward pass):
        backpropagation in closed form, every sample at once. Columns in the order of
        :meth:`nonlinear_names`; written into ``out`` when given."""
        pres, outs = layers if layers is not None else self.layer_outputs(beta, zs)
        params = self._split(beta)
        n = zs.shape[0]
        if out is None:
            out = np.empty((n, len(beta)))
        offsets = {k: i for k, _, i in self._pieces}
        with torch.no_grad():
            grad = torch.from_numpy(np.ascontiguousarray(w_out, dtype=np.float64))
            for li in range(len(pres) - 1, -1, -1):
                # Sensitivity of f_NN to this layer's pre-activations (N, width).
                delta = grad * DERIVATIVES[self.mlp.activation](pres[li], outs[li])
                inputs = outs[li - 1] if li > 0 else zs
                w_at, b_at = offsets[f"hidden.{li}.weight"], offsets[f"hidden.{li}.bias"]
                width, fan_in = delta.shape[1], inputs.shape[1]
                dw = torch.from_numpy(out[:, w_at:w_at + width * fan_in]).view(n, width, fan_in)
                torch.mul(delta[:, :, None], inputs[:, None, :], out=dw)
                out[:, b_at:b_at + width] = delta.numpy()
                if li > 0:
                    grad = delta @ params[f"hidden.{li}.weight"]
        return out

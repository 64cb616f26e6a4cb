"""The activations of a PGNN's hidden layers, each defined once (:data:`ACTIVATIONS`): its law
over an array namespace (:mod:`clm_sim.namespace`: numpy, and the export's C and ONNX), the
torch module the network trains with, and that module's derivative for the training's closed-form
Jacobian. The names of this table are the ones a config's ``pgnn.activation`` accepts.

No torch at import: the settings and the export read the names and the laws without it.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass


@dataclass(frozen=True)
class Activation:
    """One activation.

    ``law(x, xp)``: its value in the array namespace ``xp``, as torch computes it (to rounding);
    ``module(nn)``: the ``torch.nn`` module the network applies; ``derivative(pre, out)``:
    ``d act / d pre`` (torch tensors) from the pre-activation and the module's output.
    """

    law: Callable
    module: Callable
    derivative: Callable


def _sigmoid_derivative(pre, out):
    return out * (1 - out)


def _softplus_derivative(pre, out):
    import torch

    # nn.Softplus() is linear above its threshold (pre > 20), as its own backward is.
    return torch.where(pre > 20, torch.ones_like(pre), torch.sigmoid(pre))


def _silu_derivative(pre, out):
    import torch

    s = torch.sigmoid(pre)
    return s * (1 + pre * (1 - s))


def _gelu_derivative(pre, out):
    import torch

    # nn.GELU() is the exact (erf) form: x Phi(x).
    return (0.5 * (1 + torch.erf(pre * 0.5 ** 0.5))
            + pre * torch.exp(-0.5 * pre * pre) * (2 * torch.pi) ** -0.5)


def _tanh_derivative(pre, out):
    return 1 - out * out


def _relu_derivative(pre, out):
    import torch

    return (pre > 0).to(torch.float64)


ACTIVATIONS = {
    "tanh": Activation(law=lambda x, xp: xp.tanh(x), module=lambda nn: nn.Tanh(),
                       derivative=_tanh_derivative),
    "sigmoid": Activation(law=lambda x, xp: 1.0 / (1.0 + xp.exp(-x)),
                          module=lambda nn: nn.Sigmoid(), derivative=_sigmoid_derivative),
    # torch's softplus is x itself above its threshold, 20
    "softplus": Activation(law=lambda x, xp: xp.where(x > 20.0, x, xp.log1p(xp.exp(x))),
                           module=lambda nn: nn.Softplus(), derivative=_softplus_derivative),
    "silu": Activation(law=lambda x, xp: x / (1.0 + xp.exp(-x)), module=lambda nn: nn.SiLU(),
                       derivative=_silu_derivative),
    "gelu": Activation(law=lambda x, xp: 0.5 * x * (1.0 + xp.erf(x / xp.sqrt(2.0))),
                       module=lambda nn: nn.GELU(), derivative=_gelu_derivative),
    "relu": Activation(law=lambda x, xp: xp.relu(x), module=lambda nn: nn.ReLU(),
                       derivative=_relu_derivative),
}
"""The activations by the name a config gives (``pgnn.activation``)."""

ACTIVATION_NAMES = tuple(ACTIVATIONS)

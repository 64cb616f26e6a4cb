"""Array namespaces a force law is written against (as scikit-learn's ``get_namespace``).

An effect writes its force once, :meth:`clm_sim.effects.base.Effect.law` ``(y, v, u, xp)``, with
Python's arithmetic operators and the few functions below from ``xp``. :data:`NUMPY` evaluates it
on arrays (the simulator's models, the LIP, the diagnosis); the export writes the same law as C
(``controllers.export.c_law``) and as ONNX nodes (``controllers.export.onnx_graph``) through
namespaces of their own with the same members. A law uses only these:

* ``xp.pi``; ``xp.const(x)``: a number the target writes as its own literal (where a law negates
  a parameter, ``-xp.const(a)`` keeps the literal positive in the generated code);
* ``xp.sin``, ``xp.exp``, ``xp.abs``, ``xp.sign``; ``a ** b``; ``+ - * /`` and unary minus;
* for the networks' activations also ``xp.tanh``, ``xp.relu``, ``xp.log1p``, ``xp.erf``,
  ``xp.sqrt`` (a target may write ``tanh`` its own way: the C as ``1 - 2/(1 + e^2x)``);
* comparisons ``v > 0``, ``v < 0`` and ``xp.where(condition, a, b)``;
* ``xp.full_like(x, value)``: ``value`` with the shape of ``x``.
"""

from __future__ import annotations

import numpy as np


class NumpyNamespace:
    """The law on numpy arrays (float64)."""

    pi = np.pi
    sin = staticmethod(np.sin)
    exp = staticmethod(np.exp)
    abs = staticmethod(np.abs)
    sign = staticmethod(np.sign)
    where = staticmethod(np.where)
    tanh = staticmethod(np.tanh)
    log1p = staticmethod(np.log1p)
    sqrt = staticmethod(np.sqrt)

    @staticmethod
    def erf(x):
        # scipy.special imported on first use (an activation only): a fifth of a second that
        # every importer of the physics, the simulator's workers included, would pay for nothing
        import scipy.special

        return scipy.special.erf(x)

    @staticmethod
    def relu(x):
        return np.maximum(x, 0.0)

    @staticmethod
    def const(x: float) -> float:
        return float(x)

    @staticmethod
    def full_like(x, value: float):
        # value + 0 x (not np.full): the first step of numpy's own polyval, so that a law written
        # in Horner form gives polyval's bits
        return value + np.asarray(x) * 0.0


NUMPY = NumpyNamespace()

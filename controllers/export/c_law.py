"""The C namespace of a force law (:mod:`clm_sim.namespace`): an effect's
:meth:`~clm_sim.effects.base.Effect.law` evaluated on :class:`CExpr` values writes its C
expression of ``y`` (m), ``v`` (m/s) and ``base`` (N: the physical force), with the generated
file's ``R()`` literals and maths macros (``SIN``, ``EXP``, ``FABS``, ``SGN``, ``POW``).
Parentheses follow C's precedence and keep the law's order of operations (the rounding of every
operation is the numpy law's)."""

from __future__ import annotations

from clm_sim.errors import UserError
from clm_sim.rigid_body import rigid_body
from controllers.activations import ACTIVATIONS
from controllers.export.c_literals import c_real

# precedence: 0 an operand (literal, name, call, parenthesised), 1 unary, 2 * /, 3 + -, 4 < >
_ATOM, _UNARY, _MUL, _ADD, _REL = range(5)


class CExpr:
    """A C expression and its precedence; arithmetic on it writes C."""

    __array_priority__ = 1000  # numpy scalars defer to these operators

    def __init__(self, text: str, prec: int = _ATOM, terms: tuple = ()):
        self.text, self.prec = text, prec
        self.terms = terms  # a sum's terms, each with its sign ("+ x"), for the layout

    def laid_out(self, first: int, indent: str) -> str:
        """The text with the terms of a sum after the ``first`` on a new line at ``indent``."""
        if len(self.terms) <= first:
            return self.text
        return " ".join(self.terms[:first]) + "\n" + indent + " ".join(self.terms[first:])

    def __str__(self) -> str:
        return self.text

    @staticmethod
    def of(x) -> "CExpr":
        return x if isinstance(x, CExpr) else CExpr(c_real(x))

    def _binary(self, other, op: str, prec: int, reflected: bool = False) -> "CExpr":
        left, right = (CExpr.of(other), self) if reflected else (self, CExpr.of(other))
        lt = left.text if left.prec <= prec else f"({left.text})"
        rt = right.text if right.prec < prec else f"({right.text})"  # keeps the law's order
        terms = ()
        if prec == _ADD:
            terms = (left.terms if left.terms and lt == left.text else (lt,)) + (f"{op} {rt}",)
        return CExpr(f"{lt} {op} {rt}", prec, terms)

    def __add__(self, o): return self._binary(o, "+", _ADD)
    def __radd__(self, o): return self._binary(o, "+", _ADD, True)
    def __sub__(self, o): return self._binary(o, "-", _ADD)
    def __rsub__(self, o): return self._binary(o, "-", _ADD, True)
    def __mul__(self, o): return self._binary(o, "*", _MUL)
    def __rmul__(self, o): return self._binary(o, "*", _MUL, True)
    def __truediv__(self, o): return self._binary(o, "/", _MUL)
    def __rtruediv__(self, o): return self._binary(o, "/", _MUL, True)
    def __gt__(self, o): return self._binary(o, ">", _REL)
    def __lt__(self, o): return self._binary(o, "<", _REL)

    def __neg__(self):
        return CExpr("-" + (self.text if self.prec <= _UNARY else f"({self.text})"), _UNARY)

    def __pow__(self, o):
        return CExpr(f"POW({self}, {CExpr.of(o)})")


def _call(name: str):
    return lambda x: CExpr(f"{name}({CExpr.of(x)})")


class CNamespace:
    """The members of :mod:`clm_sim.namespace` in C."""

    pi = CExpr(c_real(3.141592653589793))
    sin, exp = staticmethod(_call("SIN")), staticmethod(_call("EXP"))
    abs, sign = staticmethod(_call("FABS")), staticmethod(_call("SGN"))
    log1p, erf = staticmethod(_call("LOG1P")), staticmethod(_call("ERF"))
    sqrt = staticmethod(_call("SQRT"))

    @staticmethod
    def tanh(x):
        # 1 - 2/(1 + e^2x): one exp instead of libm's expm1-based tanh; its absolute error is a
        # few 1e-16 (what the force sees through the output weights), and no overflow: e^2x = inf
        # -> 1.
        return 1.0 - 2.0 / (1.0 + C.exp(2.0 * x))

    @staticmethod
    def relu(x):
        return C.where(x > 0.0, x, C.full_like(x, 0.0))

    @staticmethod
    def const(x: float) -> CExpr:
        return CExpr(c_real(x))

    @staticmethod
    def full_like(x, value: float) -> CExpr:
        return CExpr(c_real(value))

    @staticmethod
    def where(condition, a, b) -> CExpr:
        return CExpr(f"({CExpr.of(condition)} ? {CExpr.of(a)} : {CExpr.of(b)})")


C = CNamespace()


def rigid_body_c(theta, a: str, v: str, s: str, y: str) -> str:
    """The C of :func:`clm_sim.rigid_body.rigid_body` on the C expressions ``a``, ``v``, ``s``,
    ``y`` (two terms a line)."""
    out = rigid_body(theta, CExpr(a), CExpr(v), CExpr(s), CExpr(y))
    return out.laid_out(2, "        ")


def activation_c(name: str) -> str:
    """The C expression of the activation ``name`` (its law) of ``x``."""
    return CExpr.of(ACTIVATIONS[name].law(CExpr("x"), C)).text


def effect_c(effect) -> str:
    """The C expression of ``effect``'s force (N) of ``y``, ``v`` and ``base``; an additive one
    in parentheses, so that it stands as a term."""
    try:
        out = CExpr.of(effect.law(CExpr("y"), CExpr("v"), CExpr("base"), C))
    except NotImplementedError:
        raise UserError(f"export: effect {effect.type!r} has no C form (no law of y, v, u)") \
            from None
    return out.text if out.prec < _ADD else f"({out.text})"

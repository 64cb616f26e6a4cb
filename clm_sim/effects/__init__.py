"""The vocabulary of physical force effects, shared by the simulator, the models and the diagnosis.

Each effect is a small frozen dataclass with named SI parameters. It knows three things:

* ``law(y, v, u, xp)``: the force (N) it adds to what the motor must supply, in the inverse-model
  sign convention ``u = m*a + fv*v + fc*sign(v) + fk*y + sum(effect.force)``, written once against
  an array namespace ``xp`` (:mod:`clm_sim.namespace`): ``force(y, v, u)`` is the law on numpy
  arrays, and the export writes the same law as C and as ONNX nodes, so that a new effect exports
  with no edit to ``controllers/export/``. In the plant the force enters with the opposite sign
  (``m*a = u - ... - sum(effect.force)``);
* ``regressors(y, v, u)``: the columns it contributes to a linear-in-the-parameters model when its
  nonlinear parameters (periods, velocities) are held fixed, and ``from_coefficients`` to rebuild the
  effect from the least-squares coefficients of those columns. The columns are the law's: a force
  that is one parameter times a shape (``Effect.gain``) has the law at that parameter = 1 as its
  column; the periodic forces share one angle and their sine and cosine columns;
* ``lower(terms)``: how it appears in the compiled simulator, as primitive terms of
  :class:`KernelTerms` (position harmonics, motor-force ripple and the track end's motor-force
  factor, a position polynomial, Stribeck friction, direction-dependent friction, a constant
  force, Dahl pre-sliding friction, a taut cable carrier's saturating pull). The
  simulator keeps this lowering of its own: it integrates the *forward* plant, where friction at
  rest is stiction up to the breakaway level (not the law's value at ``v = 0``) and the ripple
  multiplies the motor force, in a numba kernel compiled once for these fixed term arrays (a law
  compiled per model would cost a compilation per plant); the tests hold the kernel's forces in
  motion to the laws.

Most forces are functions of the instantaneous ``(y, v, u)``. Pre-sliding friction has a state
(the bristle deflection), but Dahl's state is a function of the position *path* alone, so its
``force`` and ``regressors`` read ``y`` as an ordered path (a record's samples, any sample rate).

``EFFECTS`` maps a config ``type:`` to its class; it is the only place names are resolved. The
classes: :mod:`~clm_sim.effects.base` (the ``Effect`` contract and the simulator's terms),
:mod:`~clm_sim.effects.position` (forces of the position: cogging, commutation ripple, the track's
end, the cable carrier, a constant force), :mod:`~clm_sim.effects.friction` (Stribeck, pre-sliding
and direction-dependent friction).
"""

from __future__ import annotations

import numpy as np

from clm_sim.effects.base import Effect, KernelTerms
from clm_sim.effects.friction import FrictionAsymmetry, Presliding, Stribeck
from clm_sim.effects.position import (CableSlab, CableTaut, Cogging, ForceOffset, ForceRipple,
                                      TrackEnd)

EFFECTS: dict[str, type[Effect]] = {
    cls.type: cls for cls in (Cogging, ForceRipple, CableSlab, CableTaut, Stribeck,
                              FrictionAsymmetry, ForceOffset, Presliding, TrackEnd)
}
"""The effect classes by their config ``type:`` (the one place names are resolved).

A config's ``effects:`` entry ``{type: cogging, amplitude: 3, ...}`` is
``EFFECTS["cogging"](amplitude=3, ...)``; each class is a frozen dataclass with named SI
parameters, its force law, its regressor columns and its simulator terms.

Examples
--------
>>> from clm_sim import EFFECTS
>>> sorted(EFFECTS)  # doctest: +NORMALIZE_WHITESPACE
['cable_slab', 'cable_taut', 'cogging', 'force_offset', 'force_ripple', 'friction_asymmetry',
 'presliding', 'stribeck', 'track_end']
>>> cogging = EFFECTS["cogging"](amplitude=3.0, period=0.016)
>>> cogging.as_config()
{'type': 'cogging', 'amplitude': 3.0, 'period': 0.016, 'phase': 0.0}
>>> float(cogging.force(0.004, 0.0, 0.0))  # N at y = 4 mm: a quarter period
3.0
"""


def lower_effects(effects) -> KernelTerms:
    """Collect the kernel terms of a sequence of effects."""
    terms = KernelTerms()
    for effect in effects:
        effect.lower(terms)
    return terms


def total_force(effects, y, v, u) -> np.ndarray:
    """Sum of the effects' forces (N, inverse-model sign), vectorised over samples."""
    out = np.zeros(np.shape(y), dtype=float)
    for effect in effects:
        out = out + effect.force(y, v, u)
    return out

"""Each effect's force law is written once (``Effect.law(y, v, u, xp)``): numpy, the simulator's
kernel, the exported C and the exported ONNX graph compute the same force.

Oracle: the numpy law through the product's own LIP (``feedforward``), against which the C
(compiled, called through ctypes) and ONNX Runtime are held; the kernel's separate lowering (the
forward plant's primitive terms) is held to the law in motion. A new effect defined here, in the
test, exports to C and ONNX with no edit to ``controllers/export/``.
"""

from __future__ import annotations

import ast
import math
from dataclasses import dataclass
from pathlib import Path
from typing import ClassVar

import numpy as np
import pytest

from clm_sim.effects import lower_effects
from clm_sim.effects.base import Effect
from clm_sim.effects.friction import FrictionAsymmetry, Stribeck
from clm_sim.effects.position import (CableSlab, CableTaut, Cogging, ForceOffset, ForceRipple,
                                      TrackEnd)
from clm_sim.errors import UserError
from clm_sim.kernel import applied_force, friction_extra, friction_levels
from controllers.activations import ACTIVATION_NAMES
from controllers.export import c_source
from controllers.export.cbuild import CompiledFeedforward, compiler
from controllers.export.window import from_lip
from controllers.lip import LIPFeedforward

TS = 1e-4
THETA = {"mass": 4.0, "viscous": 20.0, "coulomb": 3.0, "stiffness": 50.0}
# The export equals the product to rounding (docs/export.md: 0 for a LIP, where the C evaluates
# the law's operations in its order); 1e-12 of the peak leaves room for libm's sin/exp/pow.
REL = 1e-12
EXPORT = Path(__file__).resolve().parents[1] / "controllers" / "export"

EFFECTS = {
    "cogging": Cogging(amplitude=1.5, period=0.016, phase=0.3),
    "force_ripple": ForceRipple(amplitude=0.02, period=0.032, phase=-0.4),
    "cable_slab": CableSlab(coefficients=(0.5, 10.0, -30.0, 2000.0), center=0.01),
    "cable_taut": CableTaut(pull=3.0, reach=0.02, center=0.005),
    "stribeck": Stribeck(peak=2.0, velocity=0.002),
    "friction_asymmetry": FrictionAsymmetry(coulomb_pos=0.4, coulomb_neg=0.7, viscous_pos=1.0,
                                            viscous_neg=2.0),
    "force_offset": ForceOffset(force_n=-0.8),
    # plant-only (no feedforward identifies it), but its law exports as any other's
    "track_end": TrackEnd(start=0.02, coil_length=0.03, fringe=0.003),
}


@dataclass(frozen=True)
class QuadraticDrag(Effect):
    """A demo effect, defined only here: air or fluid drag ``drag v |v|`` (N s^2/m^2) with a
    dead band below ``v0`` (m/s), and a position bump ``bump sin(2 pi y / width)`` (N, m)."""

    drag: float = 40.0
    v0: float = 0.01
    bump: float = 0.3
    width: float = 0.05
    type: ClassVar[str] = "quadratic_drag"

    def law(self, y, v, u, xp):
        drag = xp.where(xp.abs(v) > self.v0, self.drag * v * xp.abs(v), xp.full_like(v, 0.0))
        return drag + self.bump * xp.sin(2.0 * xp.pi * y / self.width) - xp.const(0.1) * u / 50.0


def reference() -> np.ndarray:
    """Rest, smooth moves both ways with reversals and slow creeping, rest (m)."""
    t = np.arange(0.0, 0.6, TS)
    r = 0.03 * np.sin(2 * np.pi * 2.5 * t) ** 3 + 0.002 * np.sin(2 * np.pi * 11 * t) + 0.01
    return np.concatenate([np.full(300, r[0]), r, np.full(300, r[-1])])


def _rel(got, want) -> float:
    return float(np.max(np.abs(got - want)) / np.max(np.abs(want)))


def _check_exports(effect, tmp_path):
    """The LIP with ``effect`` exported to C and ONNX, each held to the product's feedforward."""
    model = LIPFeedforward.fitted(theta=THETA, effects=(effect,))
    wf = from_lip(model, TS, "law test")
    r = reference()
    want = model.feedforward(r, TS)
    assert _rel(wf.apply(r), want) < REL  # the window form
    if compiler() is not None:
        c_source.write(wf, tmp_path / "c")
        c = CompiledFeedforward(tmp_path / "c", ("-O2", "-DCLM_FF_PORTABLE"))
        assert _rel(c.stream(r), want) < REL
        assert _rel(c(wf.windows(r)[::5]), want[::5]) < REL
    onnx = pytest.importorskip("onnx")
    ort = pytest.importorskip("onnxruntime")
    from controllers.export import onnx_graph
    onnx_graph.write(wf, tmp_path / "onnx")
    onnx.checker.check_model(onnx.load(str(tmp_path / "onnx" / "clm_ff.onnx")), full_check=True)
    session = ort.InferenceSession(str(tmp_path / "onnx" / "clm_ff.onnx"),
                                   providers=["CPUExecutionProvider"])
    got = session.run(["u_ff"], {"r_window": np.ascontiguousarray(wf.windows(r))})[0]
    assert _rel(got, want) < REL


@pytest.fixture
def folders(tmp_path):
    (tmp_path / "c").mkdir()
    (tmp_path / "onnx").mkdir()
    return tmp_path


@pytest.mark.parametrize("name", sorted(EFFECTS))
def test_each_law_is_one_force_in_numpy_c_and_onnx(name, folders):
    _check_exports(EFFECTS[name], folders)


def _kernel_force(effect, y, v, u):
    """The inverse-model force of ``effect`` from the simulator's kernel terms, in motion
    (v != 0): what the motor supplies beyond ``u`` (applied_force) plus the friction beyond
    Coulomb and viscous (friction_extra)."""
    e = lower_effects([effect]).arrays()
    v_flat = friction_levels(0.0, e)[2]
    out = np.empty(len(y))
    for i in range(len(y)):
        out[i] = (u[i] - applied_force(y[i], u[i], e)
                  + friction_extra(v[i], 1.0 if v[i] > 0 else -1.0, e, v_flat))
    return out


@pytest.mark.parametrize("name", sorted(EFFECTS))
def test_the_kernels_lowering_is_the_law_in_motion(name):
    """The kernel keeps its own lowering (the forward plant: stiction at rest, ripple on the motor
    force); in motion it is the law to rounding (the ripple's u (1 + rho) - u against rho u)."""
    rng = np.random.default_rng(5)
    y = rng.uniform(-0.1, 0.1, 400)
    v = rng.choice([-1.0, 1.0], 400) * 10 ** rng.uniform(-4, 0, 400)
    u = rng.uniform(-80.0, 80.0, 400)
    law = EFFECTS[name].force(y, v, u)
    assert np.max(np.abs(_kernel_force(EFFECTS[name], y, v, u) - law)) <= \
        1e-13 * max(1.0, float(np.max(np.abs(u))))


def test_a_new_effect_exports_to_c_and_onnx_without_touching_the_export(folders):
    """QuadraticDrag is defined in this test only: its law is all the export needs."""
    effect = QuadraticDrag()
    y, v = np.array([0.01, 0.02, -0.03]), np.array([0.5, -0.005, -0.2])
    assert np.allclose(effect.force(y, v, np.zeros(3)),
                       [40.0 * 0.25 + 0.3 * math.sin(2 * math.pi * 0.2), 0.3 * math.sin(
                           2 * math.pi * 0.4), -40.0 * 0.04 + 0.3 * math.sin(-2 * math.pi * 0.6)])
    _check_exports(effect, folders)


def test_an_effect_without_a_law_is_refused_with_one_line(folders):
    @dataclass(frozen=True)
    class Lawless(Effect):
        type: ClassVar[str] = "lawless"

        def force(self, y, v, u):
            return np.zeros(np.shape(y))

    wf = from_lip(LIPFeedforward.fitted(theta=THETA, effects=(Lawless(),)), TS, "x")
    with pytest.raises(UserError, match="lawless.*no C form"):
        c_source.source(wf)
    pytest.importorskip("onnx")
    from controllers.export import onnx_graph
    with pytest.raises(UserError, match="lawless.*no ONNX form"):
        onnx_graph.model(wf)


def test_the_export_imports_no_effect_class():
    """controllers/export/ reaches effects only through their law (no isinstance chain)."""
    for path in EXPORT.glob("*.py"):
        tree = ast.parse(path.read_text())
        for node in ast.walk(tree):
            if isinstance(node, ast.ImportFrom):
                assert not (node.module or "").startswith("clm_sim.effects"), path.name
            if isinstance(node, ast.Import):
                assert not any(a.name.startswith("clm_sim.effects") for a in node.names), \
                    path.name
        assert "isinstance(e," not in path.read_text(), path.name


@pytest.mark.parametrize("name", ACTIVATION_NAMES)
def test_each_activation_law_is_torchs(name):
    """The activations are written once too (controllers.activations, evaluated by numpy, the C
    and ONNX; the network tests of test_export.py hold those to the product): the numpy law is
    the PGNN's torch activation to rounding over the whole range (saturation, e^x overflow)."""
    torch = pytest.importorskip("torch")
    from controllers.activations import ACTIVATIONS
    from controllers.export.window import activate
    x = np.concatenate([np.linspace(-40.0, 40.0, 4001), [-800.0, -710.0, 710.0, 800.0, 0.0]])
    want = ACTIVATIONS[name].module(torch.nn)(torch.from_numpy(x)).numpy()
    assert np.all(np.abs(activate(name, x) - want) <= 4e-16 * np.maximum(1.0, np.abs(x)))

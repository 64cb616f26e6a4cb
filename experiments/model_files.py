"""The simulation's model of a machine: a plant and, where known, its feedback controller.

A model file is YAML with a ``plant:`` mapping (``mass`` kg, ``viscous`` N*s/m, ``coulomb`` N,
``stiffness`` N/m, ``effects`` in the simulator's vocabulary, ``encoder_resolution`` m) and
optionally a ``controller:``, either a PID design (the keys of ``controllers.pid.PIDDesign``,
designed on the plant at the file's ``ts``) or a linear discrete law ``u = C(z) e + R(z) r``
given by ``b``, ``a`` (C on ``e = r - y``, N/m) and ``reference_b`` (FIR R on ``r``, N/m) at
sample time ``ts`` (s), and optionally ``ts`` (s), the rate of the machine's loop.
:func:`load_model` also reads a LIP parameter file and an experiment config (its ``ts``).

The model owns its sample time: a controller runs at the rate its file gives, and the diagnosis
refuses a record sampled at another. A file that gives no rate (older files) takes the one
:func:`load_model` is given, the record's in ``clm-sim diagnose``.

A model has exactly the effects its file lists, whatever the file's form: no ``effects`` key
means none (a model file that gives ``mass, viscous, coulomb, stiffness`` describes that rigid
body, not the default CLM's parasitics). ``effects: default_clm`` asks for the default CLM's
effects by name.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import scipy.signal

from clm_sim.errors import UserError, check_ts
from clm_sim.modelfile import mapping, read_json, sample_time
from clm_sim.plant import THETA_NAMES, Plant, default_effects
from clm_sim.records.files import RECORD_SUFFIXES
from clm_sim.schema import build, load_yaml
from controllers.pid import PIDDesign, design_pid
from experiments.config import ExperimentConfig, in_file

MODEL_KEYS = {"name", "description", "ts", "plant", "controller"}
NO_FORWARD_FORM = ("a PGNN feedforward is an inverse model (force from motion); it has no "
                   "open-loop form to simulate or diagnose")
DEFAULT_EFFECTS_NAME = "default_clm"


@dataclass(frozen=True)
class LinearController:
    """``u = b/a (z^-1) * (r - y) + reference_b (z^-1) * r`` (N per m), designed for ``ts`` s."""

    b: tuple[float, ...]
    a: tuple[float, ...] = (1.0,)
    reference_b: tuple[float, ...] = ()
    ts: float | None = None

    def __post_init__(self):
        if not self.b:
            raise UserError("controller: b must be non-empty (the numerator of C(z), N/m), "
                            "got []")
        if not self.a or self.a[0] == 0:
            raise UserError(f"controller: a must be non-empty and a[0] must not be 0 (the "
                            f"denominator of C(z)), got a = {list(self.a)}")
        if self.ts is not None and not (math.isfinite(self.ts) and self.ts > 0):
            raise UserError(f"controller: ts must be > 0 s, got {self.ts!r}")


@dataclass(frozen=True)
class ModelFile:
    """The schema of a model YAML file."""

    name: str = "model"
    description: str = ""
    ts: float | None = None
    plant: Plant = field(default_factory=Plant)
    controller: LinearController | PIDDesign | None = None

    def __post_init__(self):
        if self.ts is not None and not self.ts > 0:
            raise UserError(f"ts: expected a sample time > 0 s, got {self.ts!r}")


@dataclass(frozen=True)
class Controller:
    """A controller ready for a record: ``b, a`` on the error, ``reference_b`` on the reference,
    running at ``ts`` s (``None``: unknown; ``simulate`` refuses another rate otherwise)."""

    b: np.ndarray
    a: np.ndarray
    reference_b: np.ndarray
    ts: float | None = None

    def external_input(self, r: np.ndarray, y: np.ndarray, u: np.ndarray) -> np.ndarray:
        """The part of the measured ``u`` (N) the feedback does not explain (dither, feedforward,
        known disturbances), to be injected when the loop is re-simulated."""
        return u - scipy.signal.lfilter(self.b, self.a, r - y) - self.reference_force(r)

    def reference_force(self, r: np.ndarray) -> np.ndarray:
        """``R(z) r`` (N): the controller's share that acts on the reference alone."""
        if not self.reference_b.size:
            return np.zeros(len(r))
        return scipy.signal.lfilter(self.reference_b, [1.0], r)


@dataclass(frozen=True)
class SimulationModel:
    """What the simulation believes: ``plant``, if known its ``controller`` (else None), and the
    sample time ``ts`` (s) of the file it came from (None: not given)."""

    plant: Plant = field(default_factory=Plant)
    controller: Controller | None = None
    name: str = "default CLM"
    ts: float | None = None


def controller_for(spec, plant: Plant, ts: float, where: str) -> Controller | None:
    """A :class:`Controller` at sample time ``ts`` from a PID design or a linear law."""
    if spec is None:
        return None
    if isinstance(spec, PIDDesign):
        if ts is None:
            raise UserError(f"{where}: the controller's PID design needs a sample time; add "
                            f"'ts:' (s) to the file")
        pid = design_pid(mass=plant.mass, viscous=plant.viscous, stiffness=plant.stiffness,
                         design=spec, ts=ts)
        return Controller(np.asarray(pid.b, float), np.asarray(pid.a, float), np.zeros(0),
                          pid.ts)
    if spec.ts is not None and ts is not None:
        check_ts(spec.ts, ts, f"{where}: controller (ts {spec.ts:g} s in the file)")
    n = max(len(spec.b), len(spec.a))  # the compiled loop takes b and a of equal length
    pad = lambda x: np.concatenate([np.asarray(x, float), np.zeros(n - len(x))])  # noqa: E731
    return Controller(pad(spec.b), pad(spec.a), np.asarray(spec.reference_b, float),
                      spec.ts if spec.ts is not None else ts)


def is_model_file(data: dict) -> bool:
    """Whether a YAML mapping is a model file (else it may be an experiment config)."""
    return "plant" in data and set(data) <= MODEL_KEYS


def _explicit_effects(data: dict, path) -> dict:
    """``data`` with the model rule applied to its ``plant:``: no ``effects`` key means none,
    ``effects: default_clm`` the default CLM's by name. A file without ``plant:`` (an experiment
    config that names no plant) keeps the testbed's default plant, which the report shows."""
    plant = data.get("plant")
    if not isinstance(plant, dict):
        return data
    effects = plant.get("effects", [])
    if effects == DEFAULT_EFFECTS_NAME:
        effects = [e.as_config() for e in default_effects()]
    elif isinstance(effects, str):
        raise UserError(f"{path}: plant.effects must be a list of effects or "
                        f"{DEFAULT_EFFECTS_NAME!r}, got {effects!r}")
    return {**data, "plant": {**plant, "effects": effects}}


def load_model(path, ts: float | None = None) -> SimulationModel:
    r"""The simulation's model of a machine, from a file, for :func:`diagnose`.

    Parameters
    ----------
    path : str or Path
        A model file (YAML: ``plant:``, optional ``controller:`` and ``ts``), a LIP parameter
        file (``kind: lip``, as ``clm-sim identify``, ``clm-sim run`` and
        ``LIPFeedforward.save`` write it; controller unknown), a ``diagnosis.json`` (its
        extended model, at its record's sample time) or an experiment config (its plant and
        PID).
    ts : float, optional
        Sample time (s) to use when the file gives none (older files; ``clm-sim diagnose``
        passes the record's). The controller runs at the file's sample time.

    Returns
    -------
    SimulationModel
        ``plant`` (a :class:`Plant` with exactly the effects the file lists), ``controller``
        (None when unknown), ``name`` and ``ts``.

    Raises
    ------
    UserError
        A record or a PGNN (no forward form) is refused by name; a missing file, an unknown
        key or a bad value names the file and the key.

    Examples
    --------
    >>> from pathlib import Path
    >>> from clm_sim import load_model
    >>> _ = Path("model.yaml").write_text(
    ...     "ts: 1.0e-4\nplant: {mass: 20.0, effects: []}\ncontroller: {crossover_hz: 30.0}\n")
    >>> model = load_model("model.yaml")
    >>> model.plant.mass, model.plant.effects, model.ts
    (20.0, (), 0.0001)
    >>> load_model("record.csv")
    Traceback (most recent call last):
    ...
    clm_sim.errors.UserError: record.csv: a record (.csv), not a model file; a model is a .json ...
    """
    path = Path(path)
    suffix = path.suffix.lower()
    if suffix in RECORD_SUFFIXES:  # not 'cannot read (UnicodeDecodeError)'
        raise UserError(f"{path}: a record ({suffix}), not a model file; a model is a .json "
                        f"(identify's lip.json, a diagnosis.json) or a .yaml (plant:, optional "
                        f"controller:)")
    if suffix == ".pt":
        raise UserError(f"{path}: {NO_FORWARD_FORM}")
    # JSON strictly (YAML 1.1 would read 1e-05 as text); a model YAML as a config
    data = read_json(path, "model file") if suffix == ".json" else load_yaml(path)
    if data.get("kind") == "pgnn":
        raise UserError(f"{path}: {NO_FORWARD_FORM}")
    if data.get("kind") == "lip":
        return _lip_model(path, data, ts)
    if "extended_model" in data:
        return _diagnosis_model(path, data, ts)
    data = _explicit_effects(data, path)
    schema = ModelFile if is_model_file(data) else ExperimentConfig
    try:
        spec = build(schema, data, "config")
    except UserError as exc:
        raise in_file(path, exc) from None
    # An experiment config always has a ts (default 1e-4 s); only one the file writes counts.
    own = data.get("ts") if isinstance(data.get("ts"), (int, float)) else None
    linear = getattr(spec.controller, "ts", None)
    if own is not None and linear is not None:
        check_ts(linear, own, f"{path}: controller (ts {linear:g} s)")
    rate = next((x for x in (own, linear, ts) if x is not None), None)
    try:
        controller = controller_for(spec.controller, spec.plant, rate, str(path))
    except UserError as exc:  # a design error must still name the file it came from
        message = str(exc)
        raise UserError(message if message.startswith(str(path)) else f"{path}: {message}") \
            from None
    return SimulationModel(spec.plant, controller, spec.name,
                           None if rate is None else float(rate))


def _diagnosis_model(path: Path, data: dict, ts: float | None) -> SimulationModel:
    """A ``diagnosis.json``'s extended model: its plant (the model's parameters corrected, the
    effects found), at the sample time of the record it was found on; controller unknown."""
    ext = data["extended_model"]
    if not isinstance(ext, dict) or any(k not in ext for k in THETA_NAMES):
        raise UserError(f"{path}: extended_model needs {', '.join(THETA_NAMES)}")
    try:
        plant = build(Plant, {**{k: ext[k] for k in THETA_NAMES},
                              "effects": ext.get("effects") or []}, "extended_model")
        own = sample_time(mapping(data.get("record"), "record").get("sample_time_s"),
                          "record.sample_time_s")
    except UserError as exc:
        raise UserError(f"{path}: {exc}") from None
    return SimulationModel(plant, None, f"extended model of {path}", own if own is not None
                           else ts)


def _lip_model(path, data: dict, ts: float | None) -> SimulationModel:
    """An identified LIP as the model: a plant with its mass, friction and stiffness and only
    the effects identified with it, controller unknown."""
    missing = [k for k in THETA_NAMES if k not in data]
    if missing:
        raise UserError(f"{path}: a LIP parameter file (kind: lip) needs {', '.join(missing)}")
    plant = {k: data[k] for k in THETA_NAMES}
    try:
        plant = build(Plant, {**plant, "effects": data.get("effects") or []}, "plant")
    except UserError as exc:
        raise UserError(f"{path}: {exc}") from None
    try:
        own = sample_time(data.get("ts"))
        mapping(data.get("features"), "features")  # not used here, but a file's keys are read
    except UserError as exc:
        raise UserError(f"{path}: {exc}") from None
    rate = own if own is not None else ts
    return SimulationModel(plant, None, f"LIP from {data.get('source', path)}", rate)

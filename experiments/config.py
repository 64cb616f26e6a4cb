"""The experiment config: typed, frozen, strict. One YAML file -> one ``ExperimentConfig``."""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Literal

from clm_sim.errors import UserError
from clm_sim.features import FeatureMap
from clm_sim.loop import Dither
from clm_sim.plant import Plant
from clm_sim.reference import PointToPoint
from clm_sim.schema import build, load_yaml, to_plain
from controllers.pgnn_settings import (LAMBDA_KEYS, MAX_LAYERS, MAX_PARAMETERS, MAX_WIDTH,
                                       PGNNSettings, check_settings, parameter_count)
from controllers.pid import PIDDesign


@dataclass(frozen=True)
class Limit:
    """A plausibility bound: beyond ``most`` (in ``unit``) a value means runaway work, not an
    experiment; ``reason`` says why, in the refusal."""

    most: float
    unit: str
    reason: str


# Bounds on sizes, counts and time spans, refused upfront (one line) before any work.
LIMITS = {
    "seed": Limit(2 ** 63 - 1, "", "seeds are non-negative integers below 2**63 (numpy "
                  "SeedSequence)"),
    "run_samples": Limit(2e7, "samples", "one simulated run (the training run with its repeats, "
                         "or a replay) holds 9 signals of 8 bytes per sample: 2e7 samples are "
                         "1.4 GB and 33 minutes of motion at 10 kHz"),
    "stroke": Limit(10.0, "m", "beyond any linear-motor stroke: points are in m (are they in "
                    "mm?)"),
    "points": Limit(10_000, "points", "a reference of more points is not a point-to-point test"),
    "seeds": Limit(100, "seeds", "100 seeds estimate a mean to a tenth of the seed-to-seed "
                   "spread; more only multiply the fits"),
    "hidden": Limit(MAX_WIDTH, "neurons", "a hidden layer this wide is beyond what a few seconds "
                    "of force data can identify"),
    "layers": Limit(MAX_LAYERS, "layers", "deeper networks are beyond what a force record "
                    "identifies"),
    "max_iter": Limit(100_000, "iterations", "a fit that has not converged in 1e5 iterations "
                      "will not"),
    "restarts": Limit(100, "restarts", "each restart is a full fit"),
    "fits": Limit(1000, "fits", "seeds times restarts summed over the rows: minutes each"),
    "parameters": Limit(MAX_PARAMETERS, "", "a fit's Jacobian holds samples x parameters "
                        "numbers: 2e4 "
                        "parameters on the 6250 samples of a 50 s training run at 8 ms "
                        "are 1 GB"),
    "total_samples": Limit(2e8, "samples", "a closed-loop replay simulates ~1e6 samples per "
                           "second and core with its feedforward: 2e8 samples are ~3 minutes "
                           "of one core (the paper table: 2.7e7)"),
}


def _limit(key: str, name: str, value, detail: str = "") -> None:
    limit = LIMITS[name]
    if value > limit.most:
        raise UserError(f"{key}: {value:.6g}{' ' + limit.unit if limit.unit else ''}{detail} "
                        f"exceeds the limit of {limit.most:.6g}: {limit.reason}")


def check_limits(config: "ExperimentConfig") -> None:
    """Refuse a config whose sizes, counts or time spans exceed :data:`LIMITS` (without
    sampling anything: durations come from the references' closed form)."""
    if config.seed < 0:
        raise UserError(f"seed: expected a non-negative integer, got {config.seed}")
    _limit("seed", "seed", config.seed)
    for name, ref in config.references.items():
        _limit(f"references.{name}.points_m", "stroke", max(abs(p) for p in ref.points_m))
        _limit(f"references.{name}.points_m", "points", len(ref.points_m))
    training = config.references[config.training.reference]
    runs = [("training", training.duration_s() * config.training.repeats)]
    runs += [(f"references.{name}", config.references[name].duration_s())
             for name in config.replay]
    for key, duration in runs:
        _limit(key, "run_samples", duration / config.ts,
               f" ({duration:.6g} s at ts = {config.ts:g} s)")
    _limit("training.dither.hold_samples", "run_samples", config.training.dither.hold_samples)
    fits = 0
    for i, spec in enumerate(config.feedforwards):
        key = f"feedforwards[{i}]"
        _limit(f"{key}.seeds", "seeds", spec.seeds)
        if spec.kind != "pgnn":
            continue
        widths = (spec.hidden,) if isinstance(spec.hidden, int) else spec.hidden
        _limit(f"{key}.hidden", "layers", len(widths))
        _limit(f"{key}.hidden", "hidden", max(widths))
        _limit(f"{key}.hidden", "parameters", parameter_count(tuple(widths)),
               f" network parameters (hidden {list(widths)})")
        _limit(f"{key}.pgnn.max_iter", "max_iter", spec.pgnn.max_iter)
        _limit(f"{key}.pgnn.restarts", "restarts", spec.pgnn.restarts)
        fits += spec.seeds * spec.pgnn.restarts
    _limit("feedforwards", "fits", fits)
    if config.data is None:  # a data: config simulates nothing
        total, detail = simulated_samples(config)
        _limit("config", "total_samples", total, f" simulated ({detail})")


def simulated_samples(config: "ExperimentConfig") -> tuple[float, str]:
    """The samples a config simulates in all (the training run, and every reference replayed
    once per seed of every row), and how they add up; from the references' closed form."""
    training = config.references[config.training.reference].duration_s() \
        * config.training.repeats / config.ts
    replay = sum(config.references[name].duration_s() for name in config.replay) / config.ts
    runs = sum(spec.seeds for spec in config.feedforwards)
    total = training + runs * replay
    return total, (f"{training:.3g} in training + {runs} replays x {replay:.3g} samples of "
                   f"{', '.join(config.replay) or 'no reference'}")


def _default_references() -> dict[str, PointToPoint]:
    return {
        # r1: the training range, back and forth between -0.1 and 0.1 m.
        "r1": PointToPoint(points_m=(0.0, 0.1, -0.1, 0.1, -0.1, 0.0), dwell_s=0.25),
        # r2: leaves it, 0 to 0.17 m.
        "r2": PointToPoint(points_m=(0.0, 0.17, 0.0, 0.17, 0.0), dwell_s=0.25),
    }


@dataclass(frozen=True)
class Training:
    """The identification experiment: closed loop on ``reference`` with ``dither`` added.

    Parameters
    ----------
    reference : str
        Name of the training reference among the config's ``references``.
    repeats : int
        The reference's profile is run this many times in a row (1 to 1000); it must end
        where it starts to be repeated.
    dither : Dither
        The excitation added to the controller output.

    Raises
    ------
    UserError
        ``repeats`` not an integer in 1..1000.

    Examples
    --------
    >>> from clm_sim import Dither, ExperimentConfig, Training
    >>> training = Training(reference="r1", repeats=1, dither=Dither(std_n=20.0))
    >>> ExperimentConfig(training=training).training.dither.std_n   # N
    20.0
    """

    reference: str = "r1"
    repeats: int = 3
    dither: Dither = field(default_factory=Dither)

    def __post_init__(self):
        if not (isinstance(self.repeats, int) and 1 <= self.repeats <= 1000):
            raise UserError(f"repeats: expected an integer in 1..1000, got {self.repeats!r}")


@dataclass(frozen=True)
class FeedforwardSpec:
    """One row of the table: a feedforward and how it is identified.

    Parameters
    ----------
    kind : {"none", "lip", "pgnn"}
        Feedback only, the LIP, or a PGNN.
    training : str, optional
        PGNN only: ``simultaneous``, ``sequential`` or ``pinn``.
    lam : float, optional
        PGNN only: regularization weight toward theta_LIP (physical units; ``lambda`` in a
        config); required for ``simultaneous`` (0 for none), not allowed for ``sequential``.
    hidden : int or tuple of int, optional
        PGNN only: neurons n_l of the hidden layer, or the widths of several (``(32, 32)``).
    seeds : int
        Training seeds (network draws) averaged in the table, >= 1.
    name : str, optional
        The row's label in the table (default: made from the settings).
    pgnn : PGNNSettings
        The ``pgnn:`` options of the row.

    Raises
    ------
    UserError
        A PGNN without ``training`` or ``hidden``, a setting its constraint refuses, PGNN
        settings on another kind, ``seeds`` < 1.

    Examples
    --------
    >>> from clm_sim import FeedforwardSpec
    >>> FeedforwardSpec(kind="lip").label()
    'LIP'
    >>> row = FeedforwardSpec.pgnn_row(training="simultaneous", lam=0.01, hidden=16, seeds=5,
    ...                                settings={"max_iter": 50})
    >>> row.label(), row.pgnn.max_iter
    ('PGNN simultaneous, lambda=0.01, n_l=16', 50)
    >>> FeedforwardSpec(kind="pgnn", training="sequential", lam=0.1, hidden=16)
    Traceback (most recent call last):
    ...
    clm_sim.errors.UserError: lambda does not apply to a sequential pgnn (theta_phy is fixed ...
    """

    kind: Literal["none", "lip", "pgnn"]
    training: str | None = None
    lam: float | None = None
    hidden: int | tuple[int, ...] | None = None
    seeds: int = 1
    name: str | None = None
    pgnn: PGNNSettings = field(default_factory=PGNNSettings)
    aliases = {k: v for k, v in LAMBDA_KEYS.items() if v == "lam"}

    def __post_init__(self):
        if self.kind == "pgnn":
            if self.training is None or self.hidden is None:
                raise UserError("a pgnn feedforward needs 'training' and 'hidden'")
            # the constraints of the one table (controllers.pgnn_settings.CONSTRAINTS)
            check_settings({"training": self.training, "hidden": self.hidden,
                            **({} if self.lam is None else {"lam": self.lam})})
            if self.training == "simultaneous" and self.lam is None:
                raise UserError("a simultaneous pgnn needs 'lambda' (0 for none)")
            if self.training == "sequential" and self.lam:
                raise UserError("lambda does not apply to a sequential pgnn (theta_phy is fixed "
                                "at theta_LIP)")
            if self.training == "pinn" and not self.pgnn.pinn_weight > 0:
                raise UserError("a pinn pgnn needs pgnn.pinn_weight > 0")
        elif self.training is not None or self.lam is not None or self.hidden is not None:
            raise UserError(f"training, lambda and hidden apply to kind pgnn, not {self.kind}")
        if not (isinstance(self.seeds, int) and self.seeds >= 1):
            raise UserError(f"seeds must be an integer >= 1, got {self.seeds!r}")

    @classmethod
    def pgnn_row(cls, *, training: str, lam: float | None, hidden: int | tuple[int, ...],
                 seeds: int = 1,
                 settings: dict | None = None) -> "FeedforwardSpec":
        """A PGNN row from keyword settings (see :class:`PGNNSettings`)."""
        return cls(kind="pgnn", training=training, hidden=hidden, seeds=seeds,
                   lam=lam if training != "sequential" else (lam or None),
                   pgnn=PGNNSettings(**(settings or {})))

    def pgnn_settings(self) -> dict:
        """The keyword arguments of ``controllers.pgnn.PGNNFeedforward`` for this row: its
        ``hidden``, ``training``, ``lam`` and ``settings`` (the ``pgnn:`` options)."""
        return {"hidden": self.hidden, "training": self.training, "lam": self.lam or 0.0,
                "settings": self.pgnn}

    def label(self) -> str:
        if self.name:
            return self.name
        if self.kind == "none":
            return "feedback only"
        if self.kind == "lip":
            return "LIP"
        lam = "" if self.training == "sequential" else f", lambda={self.lam:g}"
        widths = (self.hidden,) if isinstance(self.hidden, int) else self.hidden
        return f"PGNN {self.training}{lam}, n_l={'x'.join(map(str, widths))}"


@dataclass(frozen=True)
class Window:
    """A training window: the samples whose (filtered) position and velocity lie in these
    closed intervals (m, m/s; None: no limit on that signal)."""

    position_m: tuple[float, ...] | None = None
    velocity_m_s: tuple[float, ...] | None = None

    def __post_init__(self):
        for key in ("position_m", "velocity_m_s"):
            value = getattr(self, key)
            if value is not None and not (len(value) == 2 and value[0] < value[1]):
                raise UserError(f"{key}: expected [low, high] with low < high, got "
                                f"{list(value)!r}")

    def inside(self, y, v):
        """Boolean mask of the samples inside the window (positions ``y`` m, velocities ``v``
        m/s)."""
        import numpy as np

        mask = np.ones(len(y), dtype=bool)
        for value, x in ((self.position_m, y), (self.velocity_m_s, v)):
            if value is not None:
                mask &= (x >= value[0]) & (x <= value[1])
        return mask


@dataclass(frozen=True)
class RecordData:
    """Identification from measured records instead of the simulation (``clm-sim run`` with a
    ``data:`` section): the training record, an optional validation record, how their columns
    map onto a record (``columns``, ``scale``: as ``clm-sim identify --columns --scale``) and
    the training window. Paths relative to the current folder."""

    training: str
    validation: str | None = None
    columns: dict[str, str] | None = None
    scale: dict[str, float | str] | None = None
    window: Window = field(default_factory=Window)

    def load(self, which: str = "training"):
        """The record ``which`` (training or validation), read with ``columns`` and ``scale``;
        a missing file is an error that names the key."""
        from clm_sim.records.read import load_record

        path = getattr(self, which)
        if not Path(path).exists():
            raise UserError(f"data.{which}: file not found: {path} (paths are relative to the "
                            f"current folder {Path.cwd()})")
        return load_record(path, columns=self.columns, scale=self.scale)


# The keys only a simulation reads: a run with a data: section has its records' sample time and
# simulates nothing, so any of them there would be ignored (refused instead: refuse_unused).
SIMULATION_KEYS = ("ts", "plant", "truth", "controller", "references", "training", "replay")


def refuse_unused(data: dict) -> None:
    """Refuse (one line naming it) a key of :data:`SIMULATION_KEYS` in the YAML ``data`` of a
    config with a ``data:`` section."""
    if not isinstance(data, dict) or data.get("data") is None:
        return
    for key in data:
        if key in SIMULATION_KEYS:
            why = ("the records carry their own sample time" if key == "ts" else
                   "a run on records simulates nothing")
            raise UserError(f"{key}: has no effect with data: ({why}); remove it")


def _default_feedforwards() -> tuple[FeedforwardSpec, ...]:
    return (FeedforwardSpec(kind="none"), FeedforwardSpec(kind="lip"))


@dataclass(frozen=True)
class ExperimentConfig:
    """Everything a run needs: the YAML config of ``clm-sim run`` as a frozen structure.

    ``seed`` drives every random draw through spawned child streams. ``plant`` is what the
    simulation believes (the PID is designed on it); ``truth``, when given, is the emulated
    machine the runs are measured on (with effects the model lacks), and the run then diagnoses
    ``plant`` against it. :func:`load_config` reads one from a file.

    Parameters
    ----------
    name : str
        Names the results folder.
    seed : int
        Seed of every random draw (dither, network draws).
    ts : float
        Sample time, s, in (0, 0.1].
    plant : Plant
        The model plant.
    truth : Plant, optional
        The emulated machine (default: the runs are measured on ``plant``).
    controller : PIDDesign
        The PID's design, applied to ``plant``.
    references : dict of str to PointToPoint
        The named references (default: r1, the training range, and r2, beyond it).
    training : Training
        The identification experiment.
    features : FeatureMap
        The preprocessing of identification and replay.
    feedforwards : tuple of FeedforwardSpec
        The table's rows (default: feedback only and the LIP).
    replay : tuple of str
        The references every row is replayed on.
    data : RecordData, optional
        Identify from measured records instead of the simulation.

    Raises
    ------
    UserError
        A sample time out of range, a reference that is used but not defined, no
        feedforward, a row that cannot be fitted from records, a config that would simulate
        more samples than the limit.

    Examples
    --------
    >>> from clm_sim import ExperimentConfig, FeedforwardSpec, Plant
    >>> from clm_sim.effects import Cogging
    >>> config = ExperimentConfig(truth=Plant(effects=(Cogging(amplitude=3.0),)),
    ...                           feedforwards=(FeedforwardSpec(kind="lip"),), replay=("r2",))
    >>> sorted(config.references), config.training.repeats, config.plant.mass
    (['r1', 'r2'], 3, 18.8)
    >>> ExperimentConfig(replay=("r3",))
    Traceback (most recent call last):
    ...
    clm_sim.errors.UserError: replay[0]: reference 'r3' is not defined under 'references' ...
    """

    name: str = "experiment"
    seed: int = 0
    ts: float = 1e-4
    plant: Plant = field(default_factory=Plant)
    truth: Plant | None = None
    controller: PIDDesign = field(default_factory=PIDDesign)
    references: dict[str, PointToPoint] = field(default_factory=_default_references)
    training: Training = field(default_factory=Training)
    features: FeatureMap = field(default_factory=FeatureMap)
    feedforwards: tuple[FeedforwardSpec, ...] = field(default_factory=_default_feedforwards)
    replay: tuple[str, ...] = ("r1", "r2")
    data: RecordData | None = None

    def __post_init__(self):
        if not (0 < self.ts <= 0.1):
            raise UserError(f"ts: expected a sample time in (0, 0.1] s, got {self.ts!r}")
        uses = [("training.reference", self.training.reference)]
        uses += [(f"replay[{i}]", name) for i, name in enumerate(self.replay)]
        for key, name in uses:
            if name not in self.references:
                raise UserError(f"{key}: reference {name!r} is not defined under 'references' "
                                f"(defined: {', '.join(self.references)})")
        if not self.feedforwards:
            raise UserError("feedforwards: expected at least one entry")
        if self.data is not None:
            for i, spec in enumerate(self.feedforwards):
                if spec.kind == "none":
                    raise UserError(f"feedforwards[{i}]: kind none has nothing to identify "
                                    f"from a record (data:)")
                if spec.kind == "lip" and spec.seeds != 1:
                    raise UserError(f"feedforwards[{i}].seeds: the least-squares LIP of a "
                                    f"record is one fit, without a seed (data:); remove seeds")
        check_limits(self)


def in_file(path, exc: Exception, where: str = "") -> UserError:
    """The error ``exc`` raised while checking the config read from ``path``, as one line that
    names the file (and ``where`` in it) once and the key path without its ``config`` root."""
    message = str(exc).removeprefix("config.").removeprefix("config: ")
    return UserError(f"{path}: {where + ': ' if where else ''}{message}")


def refuse_other_commands(data: dict, path) -> None:
    """A config of ``clm-sim sweep`` or ``clm-sim study`` given to ``clm-sim run``: one line
    naming the command that runs it."""
    for section, command in (("sweep", "sweep"), ("kind", "study"), ("study", "study"),
                             ("failure_map", "study"), ("mechanism", "study"),
                             ("benchmark", "study"), ("identifiability", "study")):
        if section in data:
            raise UserError(f"{path}: has a '{section}:' " + ("key" if section == "kind" else
                            "section") + f"; run it with 'clm-sim {command} {path}'")


def load_config(path, data: dict | None = None) -> ExperimentConfig:
    r"""Read and check an experiment config (YAML, read strictly into typed structures).

    Parameters
    ----------
    path : str or Path
        The YAML file (``experiments/configs/*.yaml`` are the shipped ones).
    data : dict, optional
        The file's YAML when the caller has read it already.

    Returns
    -------
    ExperimentConfig
        Every default filled in.

    Raises
    ------
    UserError
        One line that names the file and the key: an unknown key, a value of the wrong type
        or out of range, a missing file, a config of another command (``sweep:``, ``study:``).

    Examples
    --------
    >>> from pathlib import Path
    >>> from clm_sim import load_config
    >>> _ = Path("mine.yaml").write_text("ts: 1.0e-3\nplant: {mass: 20.0}\n")
    >>> config = load_config("mine.yaml")
    >>> config.ts, config.plant.mass, config.plant.viscous
    (0.001, 20.0, 172.0)
    >>> _ = Path("typo.yaml").write_text("plant: {mas: 20.0}\n")
    >>> load_config("typo.yaml")
    Traceback (most recent call last):
    ...
    clm_sim.errors.UserError: typo.yaml: plant.mas: unknown key; known keys: coulomb, effects, ...
    """
    path = Path(path)
    data = load_yaml(path) if data is None else data
    try:
        refuse_unused(data)
        return build(ExperimentConfig, data, "config")
    except UserError as exc:
        raise in_file(path, exc) from None


def resolved(config: ExperimentConfig) -> dict:
    """The config with every default filled in, as plain data (written next to every result);
    that of a run on records (``data:``) without the keys it does not use
    (:data:`SIMULATION_KEYS`: a sample time there would claim what the records contradict)."""
    plain = to_plain(config)
    if config.data is not None:
        plain = {k: v for k, v in plain.items() if k not in SIMULATION_KEYS}
    return plain

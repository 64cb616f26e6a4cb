"""The experiment config: typed, frozen, strict. One YAML file -> one ``ExperimentConfig``."""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field
from pathlib import Path
from typing import Literal

from clm_sim.errors import UserError
from clm_sim.features import FeatureMap
from clm_sim.loop import Dither
from clm_sim.plant import Plant
from clm_sim.reference import PointToPoint
from clm_sim.schema import build, load_yaml, to_plain
from controllers.pgnn_settings import PGNNSettings, check_settings
from controllers.pid import PIDDesign


def _default_references() -> dict[str, PointToPoint]:
    return {
        # r1: the training range, back and forth between -0.1 and 0.1 m.
        "r1": PointToPoint(points_m=(0.0, 0.1, -0.1, 0.1, -0.1, 0.0), dwell_s=0.25),
        # r2: leaves it, 0 to 0.17 m.
        "r2": PointToPoint(points_m=(0.0, 0.17, 0.0, 0.17, 0.0), dwell_s=0.25),
    }


@dataclass(frozen=True)
class Training:
    """The identification experiment: closed loop on ``reference`` with ``dither`` added."""

    reference: str = "r1"
    repeats: int = 3
    dither: Dither = field(default_factory=Dither)

    def __post_init__(self):
        if not (isinstance(self.repeats, int) and 1 <= self.repeats <= 1000):
            raise UserError(f"repeats: expected an integer in 1..1000, got {self.repeats!r}")


@dataclass(frozen=True)
class FeedforwardSpec:
    """One row of the table: a feedforward and how it is identified.

    kind: ``none`` (feedback only), ``lip`` or ``pgnn``; training (PGNN): ``simultaneous``,
    ``sequential`` or ``pinn``; lambda: regularization weight toward theta_LIP (physical units);
    hidden: neurons n_l of the hidden layer, or a list of widths for several (``[32, 32]``);
    seeds: training seeds averaged in the table.
    """

    kind: Literal["none", "lip", "pgnn"]
    training: str | None = None
    lam: float | None = None
    hidden: int | tuple[int, ...] | None = None
    seeds: int = 1
    name: str | None = None
    pgnn: PGNNSettings = field(default_factory=PGNNSettings)
    aliases = {"lambda": "lam"}

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
        """The keyword arguments of ``controllers.pgnn.PGNNFeedforward`` for this row."""
        return {"hidden": self.hidden, "training": self.training, "lam": self.lam or 0.0,
                **dataclasses.asdict(self.pgnn)}

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


def _default_feedforwards() -> tuple[FeedforwardSpec, ...]:
    return (FeedforwardSpec(kind="none"), FeedforwardSpec(kind="lip"))


@dataclass(frozen=True)
class ExperimentConfig:
    """Everything a run needs; ``seed`` drives every random draw through spawned child streams.

    ``plant`` is what the simulation believes (the PID is designed on it); ``truth``, when given,
    is the emulated machine the runs are measured on (with effects the model lacks), and the run
    then diagnoses ``plant`` against it (``experiments.diagnosis``).
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


def in_file(path, exc: Exception, where: str = "") -> UserError:
    """The error ``exc`` raised while checking the config read from ``path``, as one line that
    names the file (and ``where`` in it) once and the key path without its ``config`` root."""
    message = str(exc).removeprefix("config.").removeprefix("config: ")
    return UserError(f"{path}: {where + ': ' if where else ''}{message}")


def load_config(path) -> ExperimentConfig:
    """Read and check an experiment config; errors name the file and the key."""
    path = Path(path)
    data = load_yaml(path)
    try:
        return build(ExperimentConfig, data, "config")
    except UserError as exc:
        raise in_file(path, exc) from None


def resolved(config: ExperimentConfig) -> dict:
    """The config with every default filled in, as plain data (written next to every result)."""
    return to_plain(config)

"""The EMPS benchmark's settings (``benchmark:`` of its config): the records, the published
model, the reference rows' procedures, the candidates and the selection rule."""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

from clm_sim.errors import UserError
from clm_sim.schema import build, load_yaml
from controllers.idim import IDIMProtocol
from experiments.records import output_error as oe
from experiments.studies.kinds import take_kind

STRUCTURES = ("equation_error", "diagnosis")
ADDABLE = ("friction_asymmetry",)
SELECTIONS = ("minimum_mean",)


@dataclass(frozen=True)
class Baseline:
    """A published score on the same protocol: ``name``, test RMSE (mm), ``source``."""

    name: str
    test_rmse_mm: float
    source: str = ""


@dataclass(frozen=True)
class Candidate:
    """A structure fitted by simulation error: from the equation-error fit on the data at hand
    (``offset``: with its constant force) with effects ``add``-ed at 0, or the structure the
    diagnosis names there; ``hold``: parameters kept at the equation-error fit's values."""

    name: str
    structure: str = "equation_error"
    offset: bool = True
    add: tuple[str, ...] = ()
    hold: tuple[str, ...] = ()


@dataclass(frozen=True)
class BenchmarkSettings:
    """The ``benchmark:`` section (the config file says what each key means)."""

    training: str
    test: str
    columns: dict[str, str] = field(default_factory=dict)
    scale: dict[str, str | float] = field(default_factory=dict)
    init_samples: int = 20
    published_model: str = "experiments/configs/emps_model.yaml"
    published_procedure: IDIMProtocol = field(default_factory=IDIMProtocol)
    candidates: tuple[Candidate, ...] = ()
    perturbed_starts: int = 3
    seed: int = 0
    selection: str = "minimum_mean"
    cycles: int = 4
    baselines: tuple[Baseline, ...] = ()
    max_nfev: int = oe.MAX_NFEV


def load_benchmark(path) -> tuple[str, BenchmarkSettings]:
    data = take_kind(load_yaml(path), path, "emps_benchmark")
    unknown = set(data) - {"name", "benchmark"}
    if unknown or "benchmark" not in data:
        raise UserError(f"{path}: a benchmark config has 'name' and 'benchmark:' only"
                        + (f" (unknown: {', '.join(sorted(unknown))})" if unknown else ""))
    try:
        s = build(BenchmarkSettings, data["benchmark"], "benchmark")
    except UserError as exc:
        raise UserError(f"{path}: {exc}") from None
    if s.cycles < 2:
        raise UserError(f"{path}: benchmark.cycles: expected at least 2 repetitions of the "
                        f"training record's program, got {s.cycles}")
    if s.selection not in SELECTIONS:
        raise UserError(f"{path}: benchmark.selection: expected one of {', '.join(SELECTIONS)}, "
                        f"got {s.selection!r}")
    if not s.candidates:
        raise UserError(f"{path}: benchmark.candidates: expected at least one candidate")
    if s.perturbed_starts < 0:
        raise UserError(f"{path}: benchmark.perturbed_starts: expected >= 0, got "
                        f"{s.perturbed_starts}")
    for i, c in enumerate(s.candidates):
        where = f"{path}: benchmark.candidates[{i}]"
        if c.structure not in STRUCTURES:
            raise UserError(f"{where}.structure: expected one of {', '.join(STRUCTURES)}, got "
                            f"{c.structure!r}")
        bad = [a for a in c.add if a not in ADDABLE]
        if bad:
            raise UserError(f"{where}.add: expected among {', '.join(ADDABLE)}, got {bad[0]!r}")
        bad = [h for h in c.hold if h not in oe.UNITS]
        if bad:
            raise UserError(f"{where}.hold: expected among {', '.join(oe.UNITS)}, got "
                            f"{bad[0]!r}")
    names = [c.name for c in s.candidates]
    if len(set(names)) != len(names):
        raise UserError(f"{path}: benchmark.candidates: two candidates named alike")
    return str(data.get("name", Path(path).stem)), s

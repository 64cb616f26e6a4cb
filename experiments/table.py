"""The results table shared by every experiment, typed: its rows and what a PGNN row's settings are.

    TableRow (results) -> Row.to_json -> table.json -> Row.from_json -> renderers, comparisons,
    sweep aggregates, figures, ``clm-sim compare``

``table.json`` is ``{"rows": [row, ...], "comparisons": [...], "checks": [...]}``, written and
read by :mod:`experiments.report.table_json`. A row here is the one place its keys are written
and read: :class:`Row` a simulation row (MAE in metres per reference, theta_phy per seed, a PGNN
row's fits, costs, settings and regularizers from :func:`regularizers` and
:func:`row_settings`), :class:`RecordRow` a row identified from measured records (``data:``),
:class:`FitSummary` one seed's entry of a PGNN row's ``fits`` and :class:`Stat` a mean and
spread over seeds. Keys a row does not know (a sweep's swept keys, its task key and row
position, a task's warnings) ride along in ``extra``, in their order, after the row's own. The
Python names are the files' keys but where lambda is spelled out (``lam``:
:data:`controllers.pgnn_settings.LAMBDA_KEYS`). The comparisons between rows are
:mod:`experiments.stats.comparisons`; the Markdown and CSV :mod:`experiments.report.table_md`;
the summaries over a sweep's seeds :mod:`experiments.stats.seeds`.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field
from typing import TYPE_CHECKING

from clm_sim.errors import UserError
from controllers.pgnn.fit_record import Start, ThetaPoint, fit_fields
from controllers.pgnn_settings import LAMBDA_KEYS

if TYPE_CHECKING:  # the record type, for annotations only
    from controllers.pgnn.fit_record import FitRecord

FILE_KEY = {python: key for key, python in LAMBDA_KEYS.items()}
"""Python name -> the key a results file spells lambda with."""
LAM, LAM_DIAG, CONTINUATION = (FILE_KEY[k] for k in ("lam", "lam_diag", "continuation_lam"))


@dataclass(frozen=True)
class Stat:
    """A quantity over seeds: its mean and sample std (and, for measured records, median)."""

    mean: float
    std: float
    median: float | None = None

    def to_json(self) -> dict:
        out = {"mean": self.mean, "std": self.std}
        if self.median is not None:
            out["median"] = self.median
        return out

    @classmethod
    def from_json(cls, d) -> Stat | None:
        return None if d is None else cls(d["mean"], d.get("std", 0.0), d.get("median"))


def _stats(d) -> dict[str, Stat] | None:
    return None if d is None else {k: Stat.from_json(v) for k, v in d.items()}


def _stats_json(d) -> dict | None:
    return None if d is None else {k: v.to_json() for k, v in d.items()}


@dataclass(frozen=True)
class FitSummary:
    """One seed's fit in a PGNN row's ``fits``: how it stopped, its costs (N**2), iterations,
    the path of theta_phy, its starts and the largest relative theta_phy drift from theta_LIP
    (None where not computed)."""

    seed: int
    stop: str
    cost_stop: str
    iterations: int
    iterations_total: int | None
    data_cost: float
    reg_cost: float
    grad_norm: float | None
    first_order: float | None
    theta_moved: float | None
    theta_path: tuple[ThetaPoint, ...]
    continuation_lam: float | None
    start: str | None
    objective: float
    starts: tuple[Start, ...]
    start_rtol: float | None
    agree: int
    spread: float
    multiple_optima: bool
    theta_drift: float | None = None
    iterations_run: int | None = None  # of every optimization the fit ran, listed or not
    iterations_reused: int | None = None  # of those it took from other fits' start cache

    @classmethod
    def of(cls, seed: int, f, theta_drift: float | None = None) -> FitSummary:
        """From a seed's :class:`controllers.pgnn.fit_record.FitRecord`."""
        return cls(seed, f.stop, f.cost_stop, f.iterations, f.iterations_total, f.data_cost,
                   f.reg_cost, f.grad_norm, f.first_order, f.theta_moved, tuple(f.theta_path),
                   f.continuation_lam, f.start, f.objective, tuple(f.starts), f.start_rtol,
                   f.agree, f.spread, f.multiple_optima, theta_drift, f.iterations_run,
                   f.iterations_reused)

    @property
    def converged(self) -> bool:
        return self.stop == "converged"

    def to_json(self) -> dict:
        out = {"seed": self.seed, "stop": self.stop, "cost_stop": self.cost_stop,
               "iterations": self.iterations, "iterations_total": self.iterations_total,
               "iterations_run": self.iterations_run,
               "iterations_reused": self.iterations_reused,
               "data_cost": self.data_cost, "reg_cost": self.reg_cost,
               "grad_norm": self.grad_norm, "first_order": self.first_order,
               "theta_moved": self.theta_moved,
               "theta_path": [p.to_json() for p in self.theta_path],
               CONTINUATION: self.continuation_lam, "start": self.start,
               "objective": self.objective, "starts": [s.to_json() for s in self.starts],
               "start_rtol": self.start_rtol, "agree": self.agree, "spread": self.spread,
               "multiple_optima": self.multiple_optima}
        if self.theta_drift is not None:
            out["theta_drift"] = self.theta_drift
        return out

    @classmethod
    def from_json(cls, d: dict) -> FitSummary:
        # (the objective and the starts' agreement are missing from older tables: None)
        return cls(seed=d["seed"], objective=d.get("objective"), agree=d.get("agree"),
                   spread=d.get("spread"), multiple_optima=d.get("multiple_optima"),
                   theta_drift=d.get("theta_drift"), **fit_fields(d))


@dataclass(frozen=True)
class Settings:
    """What a PGNN row is, setting by setting (``table.json``'s ``settings`` or
    ``regularizers``): file key -> value, compared key by key by
    :func:`experiments.stats.comparisons.varies`."""

    values: dict

    def get(self, key: str):
        return self.values.get(key)

    def __iter__(self):
        return iter(self.values)

    @property
    def lam(self) -> float | None:
        return self.values.get(LAM)

    @property
    def hidden(self):
        return self.values.get("hidden")

    @property
    def weight_decay(self) -> float | None:
        return self.values.get("weight_decay")

    @property
    def starts(self) -> list:
        """The starts per draw (``["draw"]`` where the row names none)."""
        return self.values.get("starts") or ["draw"]

    def to_json(self) -> dict:
        return self.values


def _settings(d) -> Settings | None:
    return None if d is None else Settings(d)


_HEAD = ("kind", "training", LAM, "hidden", "n_seeds")


@dataclass(frozen=True)
class _Common:
    kind: str
    training: str | None
    lam: float | None
    hidden: int | tuple | list | None
    n_seeds: int
    label: str
    theta_phy: dict[str, float] | None
    theta_phy_per_seed: list[dict[str, float]] | None

    def value(self, key: str):
        """The value of a row key given by name (a swept key, ``row``, ``task``, ``seed``;
        None where the row has none)."""
        if key in self.extra:
            return self.extra[key]
        return getattr(self, LAMBDA_KEYS.get(key, key), None)

    def with_extra(self, **extra):
        """This row with ``extra`` keys after its own (a sweep's swept keys and task)."""
        return type(self)(**{**self.__dict__, "extra": {**self.extra, **extra}})

    def _head(self) -> dict:
        return dict(zip(_HEAD, (self.kind, self.training, self.lam, self.hidden,
                                self.n_seeds)))


@dataclass(frozen=True)
class Row(_Common):
    """One simulation row: MAE, RMS and peak tracking error per reference (m, over seeds), the
    per-seed MAE and theta_phy, and for a PGNN row its fits, costs (N**2), theta_phy drift and
    peak network force beyond the training range (N) per reference."""

    mae: dict[str, Stat] = field(default_factory=dict)
    rms: dict[str, Stat] | None = None
    max: dict[str, Stat] | None = None
    mae_per_seed: dict[str, list[float]] | None = None
    regularizers: Settings | None = None
    settings: Settings | None = None
    fits: tuple[FitSummary, ...] | None = None
    converged: int | None = None
    at_edge: int | None = None
    data_cost: Stat | None = None
    reg_cost: Stat | None = None
    theta_drift: Stat | None = None
    network_peak_beyond_n: dict[str, Stat] | None = None
    extra: dict = field(default_factory=dict)

    @property
    def references(self) -> list[str]:
        return list(self.mae)

    def to_json(self) -> dict:
        out = {**self._head(), "mae": _stats_json(self.mae), "theta_phy": self.theta_phy,
               "label": self.label}
        if self.rms is not None:
            out.update(rms=_stats_json(self.rms), max=_stats_json(self.max),
                       mae_per_seed=self.mae_per_seed)
        out["theta_phy_per_seed"] = self.theta_phy_per_seed
        if self.fits is not None:
            out.update(regularizers=self.regularizers.to_json(),
                       settings=self.settings.to_json(),
                       fits=[f.to_json() for f in self.fits], converged=self.converged,
                       at_edge=self.at_edge, data_cost=self.data_cost.to_json(),
                       reg_cost=self.reg_cost.to_json(),
                       theta_drift=self.theta_drift.to_json(),
                       network_peak_beyond_n=_stats_json(self.network_peak_beyond_n))
        return {**out, **self.extra}

    @classmethod
    def from_json(cls, d: dict, *, with_fits: bool = True) -> Row:
        """The row of ``d``; ``with_fits`` False: without the fits' entries (what ``clm-sim
        compare`` reads is the table's columns; ``fits`` then None)."""
        own = {*_HEAD, "mae", "theta_phy", "label", "rms", "max", "mae_per_seed",
               "theta_phy_per_seed", "regularizers", "settings", "fits", "converged",
               "at_edge", "data_cost", "reg_cost", "theta_drift", "network_peak_beyond_n"}
        fits = d.get("fits") if with_fits else None
        return cls(*(d.get(k) for k in _HEAD), d["label"], d.get("theta_phy"),
                   d.get("theta_phy_per_seed"), mae=_stats(d.get("mae")) or {},
                   rms=_stats(d.get("rms")),
                   max=_stats(d.get("max")), mae_per_seed=d.get("mae_per_seed"),
                   regularizers=_settings(d.get("regularizers")),
                   settings=_settings(d.get("settings")),
                   fits=None if fits is None else tuple(map(FitSummary.from_json, fits)),
                   converged=d.get("converged"), at_edge=d.get("at_edge"),
                   data_cost=Stat.from_json(d.get("data_cost")),
                   reg_cost=Stat.from_json(d.get("reg_cost")),
                   theta_drift=Stat.from_json(d.get("theta_drift")),
                   network_peak_beyond_n=_stats(d.get("network_peak_beyond_n")),
                   extra={k: v for k, v in d.items() if k not in own})


SIDES = ("inside", "outside")


@dataclass(frozen=True)
class RecordRow(_Common):
    """One row identified from measured records: the rms force prediction error (N) per record
    and side of the training window (None where the record has no such sample), over seeds and
    per seed; the LIP's force offset (N); a PGNN row's fits and settings."""

    force_rms: dict[str, dict[str, Stat | None]] = field(default_factory=dict)
    force_rms_per_seed: list[dict[str, dict[str, float | None]]] = field(default_factory=list)
    offset_n: float | None = None
    fits: tuple[FitSummary, ...] | None = None
    converged: int | None = None
    regularizers: Settings | None = None
    settings: Settings | None = None
    extra: dict = field(default_factory=dict)

    at_edge = None  # the measured-record table does not count fits at the edge

    def to_json(self) -> dict:
        out = {**self._head(), "label": self.label,
               "force_rms": {r: {s: v and v.to_json() for s, v in sides.items()}
                             for r, sides in self.force_rms.items()},
               "force_rms_per_seed": self.force_rms_per_seed, "theta_phy": self.theta_phy,
               "theta_phy_per_seed": self.theta_phy_per_seed}
        if self.offset_n is not None:
            out["offset_n"] = self.offset_n
        if self.fits is not None:
            out.update(fits=[f.to_json() for f in self.fits], converged=self.converged,
                       regularizers=self.regularizers.to_json(),
                       settings=self.settings.to_json())
        return {**out, **self.extra}

    @classmethod
    def from_json(cls, d: dict, *, with_fits: bool = True) -> RecordRow:
        own = {*_HEAD, "label", "force_rms", "force_rms_per_seed", "theta_phy",
               "theta_phy_per_seed", "offset_n", "fits", "converged", "regularizers",
               "settings"}
        fits = d.get("fits") if with_fits else None
        return cls(*(d.get(k) for k in _HEAD), d["label"], d.get("theta_phy"),
                   d.get("theta_phy_per_seed"),
                   force_rms={r: {s: Stat.from_json(v) for s, v in sides.items()}
                              for r, sides in d["force_rms"].items()},
                   force_rms_per_seed=d.get("force_rms_per_seed") or [],
                   offset_n=d.get("offset_n"),
                   fits=None if fits is None else tuple(map(FitSummary.from_json, fits)),
                   converged=d.get("converged"),
                   regularizers=_settings(d.get("regularizers")),
                   settings=_settings(d.get("settings")),
                   extra={k: v for k, v in d.items() if k not in own})


def read_row(d: dict, *, with_fits: bool = True) -> Row | RecordRow:
    """A stored row of either kind (a simulation row, or one identified from records)."""
    return (RecordRow if "force_rms" in d else Row).from_json(d, with_fits=with_fits)


def table_rows(doc, source) -> list:
    """The ``rows`` list of a ``table.json`` document as stored (``UserError`` naming
    ``source`` where there is none)."""
    rows = doc.get("rows") if isinstance(doc, dict) else None
    if not isinstance(rows, list):
        raise UserError(f"{source}: not a clm-sim table.json (no 'rows' list)")
    return rows


def rows_entry(d, i: int, *, with_fits: bool = True) -> Row | RecordRow:
    """Entry ``i`` of a ``table.json``'s rows, of either kind; ``UserError`` where it is not
    an object with a label and an integer seed count, or not a row."""
    if not (isinstance(d, dict) and isinstance(d.get("label"), str)
            and isinstance(d.get("n_seeds"), int) and not isinstance(d["n_seeds"], bool)):
        raise UserError(f"rows[{i}]: expected an object with a 'label' and an integer "
                        f"'n_seeds'")
    try:
        return read_row(d, with_fits=with_fits)
    except (AttributeError, KeyError, TypeError, ValueError) as exc:
        raise UserError(f"rows[{i}]: not a clm-sim table row ({type(exc).__name__}: {exc})") \
            from None


def regularizers(spec, fits: list[FitRecord]) -> dict:
    """Every term and start that shaped a PGNN row besides the data: the pull toward theta_LIP
    (lambda and Lambda's diagonal), the network L2 (``weight_decay``), the other penalties, the
    continuation start (the lambda of the extra start where it applied, else 0), the
    initialization (``init``: ``lemma`` is the paper's least-squares start) and the starts whose
    best fit was kept (``starts_kept``, counted over seeds)."""
    pg = spec.pgnn
    kept = [f.start or "draw" for f in fits]
    return {LAM: spec.lam if spec.training != "sequential" else None,
            LAM_DIAG: pg.lam_diag,
            "weight_decay": pg.weight_decay,
            "orthogonal_weight": pg.orthogonal_weight,
            "pinn_weight": pg.pinn_weight if spec.training == "pinn" else 0.0,
            CONTINUATION: max((f.continuation_lam or 0.0 for f in fits), default=0.0),
            "init": "lemma" if pg.init == "optimized" else "random",
            "restarts": pg.restarts,
            "starts_kept": {k: kept.count(k) for k in sorted(set(kept))}}


# The optimizer's settings a PGNN row also compares by (PGNNSettings' names; the regularizer's
# are :data:`experiments.stats.comparisons.REGULARIZER_KEYS`).
OTHER_KEYS = ("weight_decay", "init", "restarts", "optimizer", "activation", "max_iter", "ftol",
              "theta_ftol", "decimation", "validation_fraction", "adam_lr", "starts",
              "start_rtol")


def row_settings(spec, fits: list[FitRecord]) -> dict:
    """The settings of a PGNN row that :func:`experiments.stats.comparisons.varies` compares:
    the regularizer's keys, the network weight decay, the continuation start as it ran (0
    where none did), and the optimizer's settings."""
    reg = regularizers(spec, fits)
    pg = dataclasses.asdict(spec.pgnn)
    out = {"training": spec.training, "hidden": spec.hidden}
    out.update({k: reg[k] for k in (LAM, LAM_DIAG, "orthogonal_weight", "pinn_weight",
                                    "weight_decay", CONTINUATION, "init")})
    out.update({k: pg[k] for k in OTHER_KEYS if k in pg and k not in out})
    if "starts" in out:
        out["starts"] = list(out["starts"])
    if spec.training == "sequential" and "exchange" in spec.pgnn.starts:
        # A sequential fit has no lambda to continue from; with the exchange it is compared
        # with the simultaneous rows that exchange, as one procedure applied to each.
        out[CONTINUATION] = spec.pgnn.continuation_lam
    return out


def lm_iterations(fits: list[FitSummary]) -> tuple[int, int]:
    """The LM iterations of ``fits`` (a row's fits) that they ran, and that they took from
    other fits' start cache (each optimization once: :class:`controllers.pgnn.FitRecord`); a
    table written before the record had them: the listed starts, run or taken."""
    if all(f.iterations_run is not None for f in fits):
        return (sum(f.iterations_run for f in fits), sum(f.iterations_reused for f in fits))
    return (sum(s.iterations for f in fits for s in f.starts if not s.reused),
            sum(s.iterations for f in fits for s in f.starts if s.reused))

"""The testbed: the one pipeline of clm-sim, for the CLI, the studies, the sweeps, the emulated
machine, the tests, the benchmarks and notebooks.

    config -> plant + PID + references -> dithered training run (logged) -> LIP -> PGNN per seed
           -> replay on each reference (on the truth plant when one is given) -> metrics

``Testbed``'s docstring has an example (run by ``tests/test_api_reference.py``); the README's
"Python API" section is run by ``tests/test_testbed.py``.
"""

from __future__ import annotations

import functools
import sys
import time
from dataclasses import replace
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from clm_sim.errors import UserError
from clm_sim.features import TrainingRange, held_force
from clm_sim.loop import simulate
from clm_sim.plant import Plant
from clm_sim.run import Run
from controllers.lip import LIPFeedforward
from controllers.pid import PIDController, design_pid
from experiments.config import ExperimentConfig, FeedforwardSpec, load_config, resolved
from experiments.results import (BeyondRange, ReferenceMetrics, RowResult, SeedFit, SeedResult,
                                 theta_drift)

if TYPE_CHECKING:  # torch is imported only for a PGNN
    from controllers.pgnn.starts import StartCache

# Purposes of the child random streams; the numbers are part of the reproducibility contract.
STREAM_TRAINING_DITHER = 0
STREAM_NETWORK = 1
RUNS_KEPT = 16  # optimizations kept per draw for later rows to reuse (Testbed._fit_seeds)


def stream(seed: int, purpose: int, index: int = 0) -> np.random.SeedSequence:
    """The random stream for one purpose, independent of how many rows a config has."""
    return np.random.SeedSequence(entropy=seed, spawn_key=(purpose, index))


class Progress:
    """Timed progress lines on stderr (silent when ``quiet``)."""

    def __init__(self, quiet: bool = False):
        self.quiet = quiet
        self.start = time.perf_counter()

    def __call__(self, message: str) -> None:
        if not self.quiet:
            print(f"[{time.perf_counter() - self.start:7.1f} s] {message}", file=sys.stderr,
                  flush=True)


def _silent(message: str) -> None:
    pass


class Testbed:
    """The simulated CLM under PID feedback, with its references, training experiment and
    feedforward identification: the one pipeline of clm-sim.

    ``plant`` is what the engineer believes (the PID is designed on it); runs are measured on
    ``truth`` when the config gives one (an emulated machine), else on ``plant``. Every method
    is deterministic given its seed. ``training_run`` logs the dithered identification
    experiment, ``fit_lip`` and ``fit_pgnn`` identify feedforwards from it, ``replay`` runs a
    feedforward in closed loop on a reference, ``evaluate`` and ``rows`` make the table's rows.

    Parameters
    ----------
    config : ExperimentConfig, optional
        The experiment (default: the default CLM, 30 Hz PID, r1/r2, 50 N dither);
        ``Testbed.from_config(path)`` reads one from a file or names a shipped one
        (``"paper_table"``).
    progress : callable, optional
        Called with one line per step (``None``: silent).

    Raises
    ------
    UserError
        From the methods: a reference the config does not define, a training reference that
        does not end where it starts but is repeated, a loop that diverges.

    Examples
    --------
    >>> from clm_sim import ExperimentConfig, Plant, PointToPoint, Testbed, Training
    >>> back_and_forth = PointToPoint(points_m=(0.0, 0.02, -0.02, 0.0), dwell_s=0.1)
    >>> config = ExperimentConfig(plant=Plant(effects=()), references={"r": back_and_forth},
    ...                           training=Training(reference="r", repeats=1), replay=("r",))
    >>> run = Testbed(config).training_run(seed=1)   # 2 s in closed loop, 50 N dither
    >>> testbed = Testbed(config)
    >>> testbed.ts, testbed.pid.summary()
    (0.0001, 'PID: crossover 30.0 Hz, phase margin 49.7 deg, gain margin 39.4 dB')
    >>> lip = testbed.fit_lip(run)
    >>> round(testbed.replay(None, "r").mae * 1e6), round(testbed.replay(lip, "r").mae * 1e6, 1)
    (14, 0.1)

    The MAE (m) of feedback only and with the LIP's feedforward, on the rigid body.
    """

    __test__ = False  # not a pytest class, despite its name

    def __init__(self, config: ExperimentConfig | None = None, *, progress=None):
        self.config = ExperimentConfig() if config is None else config
        self.progress = progress or _silent
        # (run seed, network seed) -> the optimizations fits of that draw ran
        # (a controllers.pgnn.starts.StartCache: PGNNFeedforward.fit_data's ``reuse``)
        self._starts: dict[tuple[int, int], StartCache] = {}
        self.warnings: list[str] = []  # suspect fits, one line each (fit_lip)
        # What the replays need that depends on neither the row nor the fit, computed once
        # for the table: the references (m), the training range and the samples of each
        # reference beyond it, a PGNN's filtered features of each reference (by FeatureMap).
        self._once: dict[tuple, object] = {}

    def __repr__(self) -> str:
        c = self.config
        truth = "" if c.truth is None else f", truth with {len(c.truth.effects)} effects"
        return (f"Testbed({c.name!r}, ts={c.ts:g} s, plant {c.plant.mass:g} kg with "
                f"{len(c.plant.effects)} effects{truth}, PID {c.controller.crossover_hz:g} Hz, "
                f"{len(c.feedforwards)} feedforwards, seed {c.seed})")

    @classmethod
    def from_config(cls, path, **kwargs) -> "Testbed":
        """A testbed from an experiment config file (errors name the file and the key). A
        relative path that is not in the current folder is looked up among the configs shipped
        with clm-sim (``experiments/configs/paper_table.yaml``, or just ``paper_table``)."""
        return cls(load_config(shipped_config(path)), **kwargs)

    # -- the set-up ---------------------------------------------------------------------------
    @property
    def ts(self) -> float:
        """Sample time (s)."""
        return self.config.ts

    @property
    def plant(self) -> Plant:
        """The model plant (what the PID is designed on)."""
        return self.config.plant

    @property
    def machine(self) -> Plant:
        """The plant every run is measured on: ``truth`` if given, else ``plant``."""
        return self.config.truth or self.config.plant

    @functools.cached_property
    def pid(self) -> PIDController:
        """The PID designed on the model plant (crossover, margins in ``pid.summary()``)."""
        p = self.config.plant
        return design_pid(mass=p.mass, viscous=p.viscous, stiffness=p.stiffness,
                          design=self.config.controller, ts=self.ts)

    def reference(self, name: str) -> np.ndarray:
        """Reference ``name`` of the config, sampled at ``ts`` (m)."""
        if name not in self.config.references:
            raise UserError(f"reference {name!r} is not defined (defined: "
                            f"{', '.join(self.config.references)})")
        return self.config.references[name].sample(self.ts).r

    def training_reference(self) -> np.ndarray:
        """The training reference, its profile repeated ``training.repeats`` times (m)."""
        cfg = self.config.training
        r = self.reference(cfg.reference)
        if cfg.repeats > 1 and r[0] != r[-1]:
            raise UserError(f"training.repeats: reference {cfg.reference!r} must end where it "
                            f"starts to be repeated")
        return np.concatenate([np.tile(r[:-1], cfg.repeats), r[-1:]])

    def meta(self, **extra) -> dict:
        return {"config": resolved(self.config), **extra}

    # -- the pipeline -------------------------------------------------------------------------
    def training_run(self, seed: int | None = None) -> Run:
        """The dithered closed-loop identification experiment on the training reference,
        measured on the machine. ``seed`` (default: the config's) draws the dither."""
        seed = self.config.seed if seed is None else seed
        r = self.training_reference()
        dither = self.config.training.dither.draw(
            len(r), np.random.default_rng(stream(seed, STREAM_TRAINING_DITHER)))
        self.progress(f"training run on {self.config.training.reference}: {len(r)} samples "
                      f"({len(r) * self.ts:.1f} s) with dither "
                      f"{self.config.training.dither.std_n:g} N")
        return simulate(self.machine, self.pid, r, self.ts, dither=dither,
                        meta=self.meta(run="training", seed=seed))

    def fit_lip(self, run: Run) -> LIPFeedforward:
        """The LIP feedforward identified from a logged run (the config's feature map), behind
        the guards of every fit (:func:`experiments.records.guards.simulated_fit_checks`): a fit
        the run cannot carry is refused; a suspect one is said through ``progress`` and kept in
        :attr:`warnings` (the runner writes them with the results)."""
        from experiments.records.guards import simulated_fit_checks

        features = self.config.features
        with np.errstate(invalid="ignore", divide="ignore", over="ignore"):
            lip = LIPFeedforward(features=features).fit(y=run.y, u=run.u, ts=run.ts)
        keep = features.fit_slice(len(run))
        lines = simulated_fit_checks(run, features, lip.theta_, lip.std_,
                                     machine_mass=self.machine.mass,
                                     samples=len(range(len(run))[keep]))
        self.progress("LIP: " + ", ".join(f"{k} {v:.4g}" for k, v in lip.theta_.items()))
        for line in lines:
            if line not in self.warnings:
                self.warnings.append(line)
                self.progress(f"warning: {line}")
        return lip

    def fit_pgnn(self, run: Run, *, hidden: int = 16, lam: float = 0.0,
                 training: str = "simultaneous", seed: int = 0,
                 lip: LIPFeedforward | None = None, **settings):
        """A PGNN feedforward identified from a logged run.

        hidden: tanh neurons; lam: regularization toward theta_LIP (simultaneous training);
        training: simultaneous, sequential or pinn; seed: the network's draw (the run's own seed
        and this index select the random stream); lip: the LIP of ``run`` (fitted if omitted);
        settings: further PGNN settings (see ``pgnn:`` in the config reference).
        """
        spec = FeedforwardSpec.pgnn_row(training=training, lam=lam, hidden=hidden,
                                        settings=settings)
        return self._fit_pgnn(spec, run, lip or self.fit_lip(run), seed)

    def _fit_pgnn(self, spec: FeedforwardSpec, run: Run, lip: LIPFeedforward, index: int):
        return self._fit_seeds(spec, run, lip, [index])[0]

    def _fit_seeds(self, spec: FeedforwardSpec, run: Run, lip: LIPFeedforward,
                   indices: list[int]) -> list:
        """PGNN fits of ``spec`` for network seeds ``indices`` (on both cores when there are
        several; every fit is single-threaded, so the pool never changes a result), with a
        progress line per finished fit."""
        from controllers.pgnn import training_data  # torch is imported only for a PGNN
        from controllers.pgnn.starts import StartCache
        from experiments.processes import workers as parallel
        run_seed = run.meta.get("seed", self.config.seed)
        data = training_data(self.config.features, y=run.y, u=run.u, ts=run.ts,
                             decimation=spec.pgnn.decimation)
        # The optimizations earlier rows ran from the same draws (a continuation row's starts
        # are the fits of its lambda = 0 and lambda = 0.01 rows): taken, not run again; a long
        # study keeps the latest only.
        payloads = [(spec.pgnn_settings(), self.config.features, data, dict(lip.theta_),
                     stream(run_seed, STREAM_NETWORK, s),
                     self._starts.setdefault((run_seed, s), StartCache(kept=RUNS_KEPT)))
                    for s in indices]
        done = []

        def report(fitted):
            model, _ = fitted
            done.append(model)
            self.progress(f"  {spec.label()}: fit {len(done)}/{len(payloads)} done "
                          f"({model.fit_.stop}, {model.fit_.iterations} it)")

        fitted = parallel.map_fits(payloads, fn=parallel.fit_pgnn_reusing, on_done=report)
        for s, (_, added) in zip(indices, fitted):  # a pool's worker filled its own copy
            self._starts[(run_seed, s)].update(added)
        return [model for model, _ in fitted]

    def fit_row(self, spec: FeedforwardSpec, run: Run, lip: LIPFeedforward) -> list:
        """The fitted models of one table row: one per seed; ``[None]`` for feedback only."""
        if spec.kind == "none":
            return [None]
        if spec.kind == "lip":
            return [lip]
        self.progress(f"  training {spec.label()}: {spec.seeds} seeds")
        models = self._fit_seeds(spec, run, lip, list(range(spec.seeds)))
        stops = [m.fit_.stop for m in models]
        if any(st != "converged" for st in stops):
            self.progress(f"  {spec.label()}: {sum(st != 'converged' for st in stops)} of "
                          f"{len(models)} fits not converged (" + ", ".join(
                              f"{stops.count(st)} {st}" for st in sorted(set(stops))
                              if st != "converged") + ")")
        return models

    def replay(self, model, reference, *, meta: dict | None = None) -> Run:
        """The closed loop on ``reference`` (a name or an array, m) with ``model``'s
        feedforward (``None``: feedback only), without dither, measured on the machine. The
        record's ``.mae``, ``.rms`` and ``.max`` are its tracking-error metrics (m)."""
        r = self.reference(reference) if isinstance(reference, str) else np.asarray(reference)
        u_ff = None if model is None else model.feedforward(r, self.ts)
        name = reference if isinstance(reference, str) else "array"
        return simulate(self.machine, self.pid, r, self.ts, u_ff=u_ff,
                        meta=meta if meta is not None else self.meta(run=f"replay on {name}"))

    def evaluate(self, spec: FeedforwardSpec, run: Run, lip: LIPFeedforward,
                 references: tuple[str, ...] | None = None) -> RowResult:
        """Fit one row and replay every seed on ``references`` (default: the config's
        ``replay``). Only the first seed's replays are kept (the others' metrics are).

        Per seed, a :class:`SeedResult`: per reference the tracking metrics (m) and, for a
        PGNN, the peak network force (N) over the reference and over its samples beyond the
        training range; and the fit (its record and the largest relative drift of theta_phy
        from theta_LIP)."""
        refs = self.config.replay if references is None else references
        models = self.fit_row(spec, run, lip)
        ts, features = self.ts, self.config.features
        # What does not depend on the fit, once per reference for every row and seed: the
        # reference, the samples beyond the training range and (PGNN) the filtered features.
        seen = {name: self._once_for(("reference", name), lambda n=name: self.reference(n))
                for name in refs}
        if spec.kind == "pgnn":
            inside = self._once_for(("inside", features), lambda: TrainingRange.of(
                features, self.reference(self.config.training.reference), ts))
            beyond_of = {name: self._once_for(("beyond", name, features),
                                              lambda r=r: inside.beyond(features, r, ts))
                         for name, r in seen.items()}
        phi_f = {}
        seeds, first = [], {}
        for s, model in enumerate(models):
            per_ref = {}
            for name in refs:
                meta = self.meta(run=f"replay {spec.label()} on {name}", seed=s)
                if spec.kind != "pgnn":
                    rep = self.replay(model, name, meta=meta)
                    per_ref[name] = ReferenceMetrics(**rep.metrics())
                else:
                    # The network's force once: it is the feedforward's part and the peak.
                    if name not in phi_f:
                        phi_f[name] = self._once_for(
                            ("features", name, model.features),
                            lambda n=name, m=model: m.filtered_features(y=seen[n], ts=ts))
                    physical, net = model.parts(phi_f[name])
                    rep = simulate(self.machine, self.pid, seen[name], ts,
                                   u_ff=held_force(physical + net), meta=meta)
                    b = BeyondRange.of(physical, net, beyond_of[name])
                    per_ref[name] = ReferenceMetrics(
                        **rep.metrics(), network_peak_n=b.network_peak_n,
                        network_peak_beyond_n=b.network_peak_beyond_n)
                if s == 0:
                    first[name] = rep
            fit = None
            if spec.kind == "pgnn":
                fit = SeedFit(s, model.fit_, theta_drift(model.theta_, lip.theta_))
            seeds.append(SeedResult(per_ref, fit))
        row = RowResult(spec, models, seeds, first)
        self.progress(f"{spec.label()}: " + ", ".join(
            f"MAE {name} {np.mean([m.references[name].mae for m in seeds]) * 1e6:.3f} µm"
            for name in refs))
        return row

    def _once_for(self, key: tuple, compute):
        """``compute()``, once per ``key`` for this testbed (its config is fixed)."""
        if key not in self._once:
            value = compute()
            if isinstance(value, np.ndarray):
                value.setflags(write=False)  # shared by every row: nobody writes into it
            self._once[key] = value
        return self._once[key]

    def rows(self) -> list[RowResult]:
        """Every row of the config's table: one training run, one LIP, each feedforward."""
        run = self.training_run()
        lip = self.fit_lip(run)
        return [self.evaluate(spec, run, lip) for spec in self.config.feedforwards]

    def with_config(self, **changes) -> "Testbed":
        """A testbed whose config differs in the given top-level fields."""
        return Testbed(replace(self.config, **changes), progress=self.progress)


CONFIGS = Path(__file__).resolve().parent / "configs"


def shipped_config(path) -> Path:
    """``path`` if it exists; else the shipped config it names (``experiments/configs/X.yaml``,
    ``X.yaml`` or ``X``), so that notebooks in any folder can name the shipped configs."""
    path = Path(path)
    if path.exists() or path.is_absolute():
        return path
    for candidate in (CONFIGS.parent.parent / path, CONFIGS / path.name,
                      CONFIGS / f"{path.name}.yaml"):
        if candidate.is_file():
            return candidate
    return path  # load_config names it: "file not found"

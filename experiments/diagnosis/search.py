"""Name the cause: one selection loop over the candidate families of
:mod:`experiments.diagnosis.families`, on held-out data, with a parsimony rule.

Significance rule (decided per step of a forward selection): with the accepted terms ``S``, a
candidate ``c`` passes when, in a blocked ``folds``-fold cross-validation over contiguous blocks
of the record, (1) it lowers the held-out MSE by at least ``min_gain`` of the current held-out MSE
and by at least ``min_explained`` of the held-out MSE of the model's own residual (the noise
floor: once the large causes are removed, ``min_gain`` alone would name model bias), (2) the
held-out MSE drops in at least ``min_folds`` of ``folds`` folds (counted among the folds whose
held-out SSE it changes by more than 1 %, at least two), (3) an F-test of ``S + c`` against ``S``
on all fitted samples, with the effective sample count of the filtered data, has
p < ``p_value``, and (4) the force it explains (RMS of the held-out MSE drop) is at least
``min_force_fraction`` of the measured force's RMS. A passing candidate must also be admissible
to its family (:meth:`Family.admissible`: physical bounds, and the family's law checked on the
data, e.g. a Stribeck curve the same force while the speed rises and falls).

Parsimony rule: "``A`` fits clearly better than ``B``" means that ``A`` passes the held-out part
of the significance rule against ``B`` (held-out MSE lower by ``min_gain`` of ``B``'s and by
``min_explained`` of the model's, in ``min_folds`` folds): what a new term must bring to join
the model, so extra parameters must earn their place as a new term would. Otherwise ``A`` and
``B`` fit about equally, and the one with fewer parameters (:meth:`Family.n_params`: linear
coefficients plus searched nonlinear parameters) is named. It is applied at each step (the
candidate with the largest held-out gain gives way to an admissible, significant candidate with
fewer parameters that it does not fit clearly better) and to the final model (each term gives way
to an alternative with fewer parameters, among all families, that fits about equally in its
place: a cable_slab whose force is nearly constant beside a cogging force is an offset).

Each step takes the candidate so chosen; the search stops when none passes, so a model that
already explains the data yields no finding. A backward pass then drops any term whose removal
from the final model raises the held-out MSE by less than these thresholds (made redundant by
later terms).

Unexplained: a candidate that passes the significance rule but is not admissible to its family,
for a reason that leaves residual unexplained (its law fails on the data, a physical bound), marks
a part of the residual that is there but that no family explains. It is reported as such
(:class:`~experiments.diagnosis.finding.Unexplained`), not named, and its columns (for a failed
law, the law's split columns: what the data holds) are held as a nuisance in every later test and
in the final passes, never in the extended model, so that it cannot pass for another effect that
happens to correlate with it.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from experiments.diagnosis.context import Candidate, Context, Rejection, Step
from experiments.diagnosis.families import REGISTRY
from experiments.diagnosis.finding import Unexplained
from experiments.diagnosis.fitting import (Significance, clearly_better, cv_of, fit_cv,
                                           significance)
from experiments.diagnosis.residual import Residual
from experiments.diagnosis.terms import Term


@dataclass(frozen=True)
class Selection:
    """The accepted steps (final model, selection order) and what stays unexplained."""

    steps: tuple[Step, ...]
    unexplained: tuple[Unexplained, ...]


@dataclass(frozen=True)
class _Tested:
    term: Term
    cols: np.ndarray
    test: Significance
    n_params: int


def _evaluate(ctx: Context, cand: Candidate) -> _Tested | None:
    """The candidate refined and tested against the current model; None unless it passes the
    significance rule."""
    res, st = ctx.res, ctx.res.settings
    family = REGISTRY[cand.term.effect]
    cand = family.refine(ctx, cand)
    cols = cand.columns(res)
    test = significance(res, ctx.x_s, ctx.fit_s, cols, ctx.base)
    force = math.sqrt(max(test.explained * ctx.base, 0.0) / len(res.z))
    if not (test.passes(res) and force >= st.min_force_fraction * res.force_rms):
        return None
    return _Tested(cand.term, cols, test, family.n_params(cand.term))


def _candidates(ctx: Context) -> list[Candidate]:
    """Every family's proposals, ranked by held-out gain on their cheap columns (positive only)."""
    res, st = ctx.res, ctx.res.settings
    scored = []
    for family in REGISTRY.values():
        if family.available(ctx):
            for cand in family.propose(ctx):
                fit1 = fit_cv(np.column_stack([ctx.x_s, cand.approx]), res.z, res.fold,
                              st.folds)
                scored.append((ctx.fit_s.cv_mse - fit1.cv_mse, cand))
    scored.sort(key=lambda s: -s[0])
    return [c for g, c in scored if g > 0]


def _simplest(ctx: Context, best: _Tested, others: list[Candidate],
              rejected: dict[str, tuple[Unexplained, np.ndarray]]) -> _Tested:
    """Parsimony: the admissible, significant candidate with the fewest parameters that ``best``
    does not fit clearly better (``best`` itself if none)."""
    chosen = best
    for cand in others:
        family = REGISTRY[cand.term.effect]
        if family.n_params(cand.term) >= chosen.n_params:
            continue
        t = _evaluate(ctx, cand)
        if t is None or clearly_better(ctx.res, t.test.fit, best.test.fit, ctx.base):
            continue
        rejection = family.admissible(ctx, t.term, t.cols)
        if rejection is None:
            chosen = t
        else:
            _note(rejected, t, rejection)
    return chosen


def _note(rejected: dict[str, tuple[Unexplained, np.ndarray]], t: _Tested,
          rejection: Rejection) -> None:
    """Keep a rejection that leaves residual unexplained (the strongest per family)."""
    name = t.term.effect
    if rejection.nuisance is None:
        return
    if name not in rejected or rejected[name][0].fraction < t.test.explained:
        rejected[name] = (Unexplained(name, rejection.reason, float(t.test.explained)),
                          rejection.nuisance)


def forward_select(res: Residual) -> Selection:
    """Forward selection of causes on ``res`` by the significance and parsimony rules of this
    module, then the final model's parsimony pass and the backward pass.

    A significant candidate whose family may not name it (:class:`Rejection` with nuisance
    columns) is unexplained: its columns are held as a nuisance in the later tests (not in the
    model), once per family, and the step is searched again."""
    st = res.settings
    steps: list[Step] = []
    base = cv_of(res).cv_mse
    held: dict[str, tuple[Unexplained, np.ndarray]] = {}
    while len(steps) < st.max_findings:
        nuisance = np.column_stack([np.zeros((len(res.z), 0))] + [c for _, c in held.values()])
        ctx = Context.of(res, steps, base, nuisance)
        ranked = _candidates(ctx)
        rejected: dict[str, tuple[Unexplained, np.ndarray]] = {}
        refused: list[_Tested] = []
        accepted = None
        for i, cand in enumerate(ranked):
            t = _evaluate(ctx, cand)
            if t is None:
                continue
            rejection = REGISTRY[t.term.effect].admissible(ctx, t.term, t.cols)
            if rejection is not None:
                _note(rejected, t, rejection)
                refused.append(t)
                continue
            accepted = _simplest(ctx, t, ranked[:i] + ranked[i + 1:], rejected)
            break
        if accepted is None:
            pair = _joint_pair(res, steps, base, ctx.nuisance, refused)
            if pair:
                steps += pair
                continue
        new = {k: v for k, v in rejected.items() if k not in held}
        if accepted is None and not new:
            break
        if accepted is None:  # hold the strongest new unexplained part, search the step again
            name = max(new, key=lambda k: new[k][0].fraction)
            held[name] = new[name]
            continue
        steps.append(Step(accepted.term, accepted.cols, accepted.test.gain,
                          accepted.test.improved, accepted.test.p))
    nuisance = np.column_stack([np.zeros((len(res.z), 0))] + [c for _, c in held.values()])
    named = {s.term.effect for s in steps}
    unexplained = tuple(sorted((u for u, _ in held.values() if u.candidate not in named
                                or REGISTRY[u.candidate].repeatable),
                               key=lambda u: -u.fraction))
    steps = prune(res, _stiffness_in_cable(simplify(res, steps, base, nuisance)), nuisance)
    return Selection(tuple(steps), unexplained)


def _joint_pair(res: Residual, steps: list[Step], base: float, nuisance: np.ndarray,
                refused: list[_Tested]) -> list[Step]:
    """A significant candidate that fails its family's checks alone may pass them beside
    another effect: pre-sliding friction (after reversals only) makes a friction curve look
    different while the speed rises and falls, and the curve makes a pre-sliding element alone
    look negative. For each refused candidate ``a`` (strongest first), the candidates proposed
    with ``a`` in the model are tried as its partner ``b``; the first pair in which each is
    significant and admissible with the other in the model is accepted as two steps."""
    def step(t: _Tested, test=None) -> Step:
        test = test or t.test
        return Step(t.term, t.cols, test.gain, test.improved, test.p)

    for a in sorted(refused, key=lambda t: -t.test.explained):
        ctx_a = Context.of(res, steps + [step(a)], base, nuisance)
        for cand in _candidates(ctx_a):
            if cand.term.effect == a.term.effect:
                continue
            b = _evaluate(ctx_a, cand)
            if b is None or REGISTRY[b.term.effect].admissible(ctx_a, b.term, b.cols):
                continue
            ctx_b = Context.of(res, steps + [step(b)], base, nuisance)
            test = significance(res, ctx_b.x_s, ctx_b.fit_s, a.cols, base)
            if test.passes(res) and \
                    REGISTRY[a.term.effect].admissible(ctx_b, a.term, a.cols) is None:
                return [step(b), step(a, test)]
    return []


def simplify(res: Residual, steps: list[Step], base: float, nuisance: np.ndarray) -> list[Step]:
    """Parsimony on the final model: each term, most parameters first, gives way to the
    alternative with the fewest parameters (any family, proposed on the residual without it)
    that is significant and admissible in its place and that it does not fit clearly better."""
    steps = list(steps)
    changed = True
    while changed:
        changed = False
        order = sorted(range(len(steps)), key=lambda i: -REGISTRY[steps[i].term.effect]
                       .n_params(steps[i].term))
        for i in order:
            n_term = REGISTRY[steps[i].term.effect].n_params(steps[i].term)
            if n_term <= 1:
                continue
            rest = steps[:i] + steps[i + 1:]
            ctx = Context.of(res, rest, base, nuisance)
            fit_term = fit_cv(np.column_stack([ctx.x_s, steps[i].cols]), res.z, res.fold,
                              res.settings.folds)
            best = None
            for cand in _candidates(ctx):
                family = REGISTRY[cand.term.effect]
                if family.n_params(cand.term) >= n_term:
                    continue
                t = _evaluate(ctx, cand)
                if t is None or clearly_better(res, t.test.fit, fit_term, base):
                    continue
                if family.admissible(ctx, t.term, t.cols) is not None:
                    continue
                if best is None or (t.n_params, t.test.fit.cv_mse) < \
                        (best.n_params, best.test.fit.cv_mse):
                    best = t
            if best is not None:
                steps[i] = Step(best.term, best.cols, best.test.gain, best.test.improved,
                                best.test.p)
                changed = True
                break
    return steps


def _stiffness_in_cable(steps: list[Step]) -> list[Step]:
    """With a ``cable_slab`` accepted, a parameter mismatch's stiffness column lies in the span
    of the polynomial (its linear part): their split is arbitrary, so the stiffness correction
    is left to the polynomial and not reported as a mismatch."""
    if not any(s.term.effect == "cable_slab" for s in steps):
        return steps
    out = []
    for s in steps:
        if s.term.effect == "parameter_mismatch" and "stiffness" in s.term.keys:
            keep = [j for j, k in enumerate(s.term.keys) if k != "stiffness"]
            term = Term("parameter_mismatch", None, tuple(s.term.keys[j] for j in keep))
            s = Step(term, s.cols[:, keep], s.gain, s.folds_improved, s.p_value)
        out.append(s)
    return out


def prune(res: Residual, steps: list[Step], nuisance: np.ndarray) -> list[Step]:
    """Backward pass: drop the weakest term while leaving it out of the final model (with the
    ``nuisance`` columns held) costs less than ``min_gain`` of the held-out MSE (a term that
    later ones made redundant)."""
    st = res.settings
    steps = list(steps)
    base = cv_of(res).cv_mse
    while steps:
        full = cv_of(res, nuisance, *[s.cols for s in steps]).cv_mse
        losses = []
        for i in range(len(steps)):
            loss = cv_of(res, nuisance, *[s.cols for j, s in enumerate(steps)
                                          if j != i]).cv_mse - full
            losses.append(min(loss / full / max(st.min_gain, 1e-12),
                              loss / base / max(st.min_explained, 1e-12)))
        worst = int(np.argmin(losses))
        if losses[worst] >= 1.0:
            break
        del steps[worst]
    return steps

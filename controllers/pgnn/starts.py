"""The optimizations of a PGNN fit, one per start, and a cache of them that later fits reuse.

A fit optimizes from one or more starts (a drawn network; with a continuation, also from the
solution regularized toward theta_LIP). What decides a start's outcome (the data, theta_LIP, the
start, the cost's weights and the optimizer's settings) is one digest,
:meth:`controllers.pgnn.PGNNFeedforward._start_key`; the optimizer is deterministic, so a start
with a key that a :class:`StartCache` holds is taken from it, bit for bit what it would compute.
A table's continuation row starts from the draws of its lambda = 0 row and the solutions of its
lambda = 0.01 row: :class:`experiments.testbed.Testbed` keeps one cache per draw and passes it to
every fit of that draw (``fit_data(reuse=)``).
"""

from __future__ import annotations

import copy
from dataclasses import dataclass
from typing import TYPE_CHECKING

if TYPE_CHECKING:
    from controllers.optim import OptimResult
    from controllers.pgnn.cost import CostTerms
    from controllers.pgnn.fit_record import Iterate
    from controllers.pgnn.network import PGNNNetwork


@dataclass(frozen=True)
class StartOutcome:
    """One optimization from one start: the network at its kept iterate (the lowest training
    cost, or held-out error with a held-out part), the optimizer's result, the accepted iterates,
    the kept one's number and its cost terms (N**2)."""

    net: PGNNNetwork
    result: OptimResult
    history: list[Iterate]
    best_iteration: int
    terms: CostTerms


class StartCache:
    """Optimizations already run, by their start's key (``_start_key``), the ``kept`` latest
    (None: all). ``take`` and ``keep`` copy, so nothing a fit goes on to change (its network
    becomes the model's) is shared with the cache or with another fit."""

    def __init__(self, kept: int | None = None):
        if kept is not None and not (isinstance(kept, int) and kept >= 1):
            raise ValueError(f"StartCache: kept must be an integer >= 1 or None, got {kept!r}")
        self.kept = kept
        self._outcomes: dict[str, StartOutcome] = {}

    def __len__(self) -> int:
        return len(self._outcomes)

    def __contains__(self, key: str) -> bool:
        return key in self._outcomes

    def __repr__(self) -> str:
        return f"StartCache({len(self)} optimizations, kept={self.kept})"

    def take(self, key: str | None) -> StartOutcome | None:
        """A copy of the outcome of ``key``; None where none is held (or ``key`` is None: an
        outcome that also depends on the random stream)."""
        if key is None or key not in self._outcomes:
            return None
        return copy.deepcopy(self._outcomes[key])

    def since(self, keys) -> StartCache:
        """The outcomes held now whose key is not in ``keys`` (those added since), in the order
        they were added, as a cache of their own (what a worker process returns: the caller
        merges them with :meth:`update`, not the whole cache back)."""
        new = StartCache(self.kept)
        new._outcomes = {k: v for k, v in self._outcomes.items() if k not in keys}
        return new

    def keys(self) -> list[str]:
        return list(self._outcomes)

    def update(self, other: StartCache) -> None:
        """Hold every outcome of ``other`` not held yet, in its order (as :meth:`keep`, without
        copying again: ``other`` is handed over)."""
        for key, outcome in other._outcomes.items():
            if key not in self._outcomes:
                self._outcomes[key] = outcome
                if self.kept is not None:
                    for old in list(self._outcomes)[:-self.kept]:
                        del self._outcomes[old]

    def keep(self, key: str | None, outcome: StartOutcome) -> None:
        """Hold a copy of ``outcome`` under ``key`` (None: not cacheable, nothing held), and
        forget the oldest beyond ``kept``."""
        if key is None or key in self._outcomes:  # the same key: the same outcome, bit for bit
            return
        self._outcomes[key] = copy.deepcopy(outcome)
        if self.kept is not None:
            for old in list(self._outcomes)[:-self.kept]:
                del self._outcomes[old]

"""Physics-guided neural network feedforward: the model and its identification
(:mod:`controllers.pgnn.model`, fitted by :mod:`controllers.pgnn.training`, stored by
:mod:`controllers.pgnn.storage`; its settings are :class:`controllers.pgnn_settings.PGNNSettings`),
the data it is fitted on (:mod:`controllers.pgnn.data`), the torch module
(:mod:`controllers.pgnn.network`), the training cost and its terms (:mod:`controllers.pgnn.cost`),
how a fit went (:mod:`controllers.pgnn.fit_record`) and the optimizations that later fits reuse
(:mod:`controllers.pgnn.starts`).

The names below are resolved on first use (PEP 562, as :mod:`clm_sim`'s): importing the package or
its torch-free modules (data, fit_record, starts) does not load torch, so a process prepares its
fits' data and starts their workers before it imports torch itself.
"""

from clm_sim.lazy import lazy_exports

# public name -> module that defines it
_EXPORTS = {
    "FitRecord": "controllers.pgnn.fit_record",
    "PGNNFeedforward": "controllers.pgnn.model",
    "TrainingData": "controllers.pgnn.data",
    "lemma_condition": "controllers.pgnn.training",
    "training_data": "controllers.pgnn.data",
}

__all__ = list(_EXPORTS)


__getattr__, __dir__ = lazy_exports(__name__, _EXPORTS, globals())

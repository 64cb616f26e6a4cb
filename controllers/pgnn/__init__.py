"""Physics-guided neural network feedforward: the model and its identification
(:mod:`controllers.pgnn.model`; its settings are :class:`controllers.pgnn_settings.PGNNSettings`),
the torch module (:mod:`controllers.pgnn.network`), the training cost and its terms
(:mod:`controllers.pgnn.cost`), how a fit went (:mod:`controllers.pgnn.fit_record`) and the
optimizations that later fits reuse (:mod:`controllers.pgnn.starts`)."""

from controllers.pgnn.fit_record import FitRecord
from controllers.pgnn.model import (
                                    PGNNFeedforward,
                                    TrainingData,
                                    lemma_condition,
                                    training_data,
)

__all__ = ["FitRecord", "PGNNFeedforward", "TrainingData", "lemma_condition", "training_data"]

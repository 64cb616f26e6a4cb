"""Physics-guided neural network feedforward: the model and its identification
(:mod:`controllers.pgnn.model`), the torch module (:mod:`controllers.pgnn.network`), the
training cost (:mod:`controllers.pgnn.cost`) and how a fit went
(:mod:`controllers.pgnn.fit_record`)."""

from controllers.pgnn.fit_record import FitRecord
from controllers.pgnn.model import (
                                    PGNNFeedforward,
                                    TrainingData,
                                    lemma_condition,
                                    training_data,
)

__all__ = ["FitRecord", "PGNNFeedforward", "TrainingData", "lemma_condition", "training_data"]

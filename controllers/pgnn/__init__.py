"""Physics-guided neural network feedforward: the model and its identification
(:mod:`controllers.pgnn.model`), the torch module (:mod:`controllers.pgnn.network`) and the
training cost (:mod:`controllers.pgnn.cost`)."""

from controllers.pgnn.model import (
                                    PGNNFeedforward,
                                    TrainingData,
                                    lemma_condition,
                                    training_data,
)

__all__ = ["PGNNFeedforward", "TrainingData", "lemma_condition", "training_data"]

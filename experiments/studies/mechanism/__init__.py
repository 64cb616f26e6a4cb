"""Finding (iii) over training records and its mechanism: the study, the hidden units one by
one, and the prediction written before a run."""

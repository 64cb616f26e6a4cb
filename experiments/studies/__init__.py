"""Studies built on the testbed: the extrapolation (lambda) study and the failure map of lambda = 0."""

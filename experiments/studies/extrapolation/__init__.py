"""The extrapolation (lambda) study: its settings, result type and figures."""

"""The failure map of lambda = 0: its settings, result type and figures."""

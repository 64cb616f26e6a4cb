"""The rigid-body force law, written once: the physical layer of the LIP, of a PGNN and of the
simulated plant's inverse model, in numpy here and as C and ONNX in the export; its regressor
columns (the LIP's features ``[a, v, sign v, y]``) are the law's own."""

from __future__ import annotations

# The law's parameters, each paired with its column of rigid_body_columns.
THETA_NAMES = ("mass", "viscous", "coulomb", "stiffness")


def rigid_body_columns(a, v, s, y) -> tuple:
    """The law's regressor columns, one per parameter of ``THETA_NAMES``: acceleration ``a``
    (m/s^2), velocity ``v`` (m/s), the sign of motion ``s``, position ``y`` (m)."""
    return (a, v, s, y)


def rigid_body(theta, a, v, s, y):
    """The rigid-body force (N), ``mass a + viscous v + coulomb s + stiffness y``, summed left to
    right (every caller's rounding is this one's). ``theta`` maps the LIP's names to SI values
    (kg, N s/m, N, N/m); ``a`` (m/s^2), ``v`` (m/s), ``s`` the sign of motion (``sign(v)``, or a
    PGNN's filtered sign feature), ``y`` (m): arrays, or any values with Python's arithmetic
    (the export's C expressions and ONNX nodes, :mod:`clm_sim.namespace`)."""
    out = None
    for name, column in zip(THETA_NAMES, rigid_body_columns(a, v, s, y)):
        term = theta[name] * column
        out = term if out is None else out + term
    return out

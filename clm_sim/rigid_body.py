"""The rigid-body force law, written once: the physical layer of the LIP, of a PGNN and of the
simulated plant's inverse model, in numpy here and as C in the export."""

from __future__ import annotations


def rigid_body(theta, a, v, s, y):
    """The rigid-body force (N), ``mass a + viscous v + coulomb s + stiffness y``, summed left to
    right (every caller's rounding is this one's). ``theta`` maps the LIP's names to SI values
    (kg, N s/m, N, N/m); ``a`` (m/s^2), ``v`` (m/s), ``s`` the sign of motion (``sign(v)``, or a
    PGNN's filtered sign feature), ``y`` (m): arrays, or any values with Python's arithmetic
    (the export's C expressions and ONNX nodes, :mod:`clm_sim.namespace`)."""
    return (theta["mass"] * a + theta["viscous"] * v + theta["coulomb"] * s
            + theta["stiffness"] * y)

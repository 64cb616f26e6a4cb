"""C literals of numbers and tables for the generated source: every value reads back to the
same bits; ``R(...)`` makes it the build's ``real`` (float or double)."""

from __future__ import annotations

import numpy as np


def c_real(x: float) -> str:
    """A double literal that reads back to the same bits, as a ``real`` (float or double)."""
    text = repr(float(x))
    if "e" not in text and "." not in text and "inf" not in text and "nan" not in text:
        text += ".0"
    return f"R({text})"


def c_array(values, per_line: int = 4) -> str:
    vals = [c_real(v) for v in np.ravel(values)]
    lines = [", ".join(vals[i:i + per_line]) for i in range(0, len(vals), per_line)]
    return "{\n    " + ",\n    ".join(lines) + "\n}"


def c_matrix(rows) -> str:
    return "{\n" + ",\n".join("    " + c_array(row, 8).replace("\n", "\n    ")
                              for row in rows) + "\n}"

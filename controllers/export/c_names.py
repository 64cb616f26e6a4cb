"""The names of the generated C: written as ``clm_ff``/``CLM_FF`` and short file-local names,
then moved under the export's ``--prefix`` (:func:`prefixed`)."""

from __future__ import annotations

import re

from controllers.export.options import DEFAULT_PREFIX

# The file-local names of clm_ff.c: macros and tables (upper case) and static functions. Each
# gets the prefix too, so that two exports compile together in one translation unit (a unity
# build) as well as side by side.
_LOCAL_MACROS = ("R", "MATHF", "SIN", "EXP", "POW", "FABS", "LOG1P", "ERF", "SQRT", "SGN",
                 "KERNEL", "IN_MEAN", "IN_STD", "OUT_W", "OUT_B", "OUT_WP", "SOS", "SOS_ZI",
                 "BACK", "INV_TS2", "INV_2TS", "HALF", "NETWORK_AVX2", "NETWORK2_AVX2", "D1", "D2",
                 "POS_UNIT", "VEL", "ACC", "POS", "RHUGE", "TINY", "COUNT_LO", "COUNT_HI")
_LOCAL_FUNCTIONS = ("physical", "advance", "flush_tiny", "features_finite", "is_finite_bits",
                    "network", "network_avx2",
                    "network1_avx2", "network2_avx2", "forward", "backward", "backward_avx2",
                    "stream_point", "raw_features", "filtered_features", "filtered_features_avx2",
                    "exp_avx2", "in_range", "clamp", "reset", "accept", "finish", "differences",
                    "steady", "fill_at_rest", "fill_window", "window_force", "sample_ok",
                    "window_ok", "extrapolated", "clip", "clip_features", "limits_key",
                    "keep_limits", "stop")
_MACRO_RE = re.compile(r"(?<![A-Za-z0-9_])(" + "|".join(_LOCAL_MACROS) + r"|[WB]\d+[TP]?)"
                       r"(?![A-Za-z0-9_])")
_FUNCTION_RE = re.compile(r"(?<![A-Za-z0-9_])(" + "|".join(_LOCAL_FUNCTIONS) + r")(?=\s*\()")


def prefixed(text: str, prefix: str = DEFAULT_PREFIX) -> str:
    """C text with every file-local name moved under the export's names (``R`` ->
    ``CLM_FF_R``, ``network(`` -> ``clm_ff_network(``) and then ``clm_ff``/``CLM_FF`` replaced
    by ``prefix``/``PREFIX``."""
    text = _MACRO_RE.sub(r"CLM_FF_\1", text)
    text = _FUNCTION_RE.sub(r"clm_ff_\1", text)
    return text.replace("clm_ff", prefix).replace("CLM_FF", prefix.upper())

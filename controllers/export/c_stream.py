"""The streaming form of the generated C and what every form shares: the status of a call, the
limits, bad samples held, the stateless call with a status (``clm_ff_eval``), the stream's init,
start from a window, step and push. The LIP (and a PGNN without feature filter) pushes into a
ring buffer and calls ``clm_ff``; a PGNN runs the forward half of its zero-phase filter as a
recursion and only the backward half as an FIR (:func:`fast_stream`). Names as written here;
:func:`controllers.export.c_source.prefixed` prefixes them."""

from __future__ import annotations

from controllers.export.c_literals import c_array, c_matrix
from controllers.export.c_runtime import runtime
from controllers.export.window import WindowFeedforward

# Both forms: step and push around the form's advance (inlined into both).
STEP_AND_PUSH = runtime("step_and_push.c")


# What every form shares: the status of a call, the limits, the stateless call with a status.
STREAM_COMMON = runtime("stream_common.c")

GENERIC_STREAM = runtime("generic_stream.c") + STEP_AND_PUSH

# The PGNN's stream: the forward sections, the backward FIR (with AVX2), init, start, advance.
FAST_STREAM = runtime("fast_stream.c")


def fast_stream(wf: WindowFeedforward) -> str:
    """The PGNN's streaming form: forward sections recursively, backward half as an FIR; state
    and arithmetic in ``clm_ff_real`` (float in the float build, whose error docs/export.md
    states)."""
    sos, zi, g = wf.forward_filter()
    return f"""
static const clm_ff_real SOS[CLM_FF_NSEC][6] = {c_matrix(sos)};
static const clm_ff_real SOS_ZI[CLM_FF_NSEC][2] = {c_matrix(zi)};
/* Causal impulse response of the sections, run backwards over the next HALF samples. */
static const clm_ff_real BACK[HALF + 1] = {c_array(g)};

""" + FAST_STREAM + STEP_AND_PUSH

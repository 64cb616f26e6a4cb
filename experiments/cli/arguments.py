"""The command line's option sets, shared by the commands that take them (``clm-sim`` parses with
them; :mod:`experiments.cli` dispatches). Only argparse here: building the parser loads no
numerics, so ``clm-sim --version`` and ``--help`` answer at once."""

from __future__ import annotations

import argparse


def workers(text: str) -> int:
    if not (text.strip().isdecimal() and int(text) >= 1):
        raise argparse.ArgumentTypeError(f"expected an integer >= 1, got {text!r}")
    return int(text)


def seconds(text: str) -> float:
    """A sample time (s): a finite number > 0 (``nan`` would contradict no model's own)."""
    try:
        value = float(text)
    except ValueError:
        value = float("nan")
    if not (value > 0 and value != float("inf")):
        raise argparse.ArgumentTypeError(f"expected a sample time in s (a finite number > 0), "
                                         f"got {text!r}")
    return value


LAST_EPOCH_S = 253_402_300_799  # 9999-12-31T23:59:59Z: the last time an ISO date writes


def check_source_date_epoch(environ) -> None:
    """Refuse a ``SOURCE_DATE_EPOCH`` (the reproducible-builds convention: whole seconds since
    1970, the export's date) that is not a whole number of seconds from 0 to
    :data:`LAST_EPOCH_S`, as one line (``UserError``), before any work."""
    from clm_sim.errors import UserError

    text = environ.get("SOURCE_DATE_EPOCH")
    if text is None:
        return
    stripped = text.strip()
    if not (stripped.isdecimal() and len(stripped) <= 12 and int(stripped) <= LAST_EPOCH_S):
        shown = text if len(text) <= 30 else text[:30] + "..."
        raise UserError(f"SOURCE_DATE_EPOCH: expected whole seconds since 1970 (0 to "
                        f"{LAST_EPOCH_S}, the year 9999), got {shown!r}")


def config(p: argparse.ArgumentParser, config: str, out: str = "") -> None:
    """The config file, ``--out`` (default ``results/<config name>``) and ``--quiet``."""
    p.add_argument("config", help=config)
    p.add_argument("--out", help=f"output folder (default results/<config name>){out}")
    p.add_argument("--quiet", action="store_true", help="no progress lines")


def cutoff(p: argparse.ArgumentParser, default: str) -> None:
    """``--regression-lowpass-hz``: the parallel filter's cut-off, named as in a config's
    ``features:`` and in the Python API (``--lowpass-hz`` still accepted, not shown)."""
    p.add_argument("--regression-lowpass-hz", type=float, metavar="HZ",
                   help=f"cut-off of the zero-phase parallel filter of the regression, Hz "
                   f"{default}")
    p.add_argument("--lowpass-hz", type=float, dest="regression_lowpass_hz",
                   help=argparse.SUPPRESS)


def record(p: argparse.ArgumentParser) -> None:
    """The record ``data`` and how its columns map onto a record (``--columns``, ``--scale``)."""
    p.add_argument("data", help="record: CSV with header t,r,y,u (SI units), .npz or .mat")
    p.add_argument("--columns", help="signal=column names in the files, e.g. y=qm,r=qg,u=vir")
    p.add_argument("--scale", help="signal=factor or signal=scalar-variable of the file, "
                   "e.g. u=gtau or y=0.001")


def protocol(p: argparse.ArgumentParser) -> None:
    """``identify``'s published-protocol options on the argparse parser ``p``, read by
    :func:`experiments.cli.identify.protocol_from_options` (controllers.idim.IDIMProtocol; the EMPS
    procedure of Janot et al. is in docs/results/emps_benchmark.md)."""
    g = p.add_argument_group("protocol (IDIM-LS) options")
    g.add_argument("--position-lowpass-hz", type=float, metavar="HZ",
                   help="Butterworth low-pass on the position before differencing (default none)")
    g.add_argument("--filter-order", type=int, default=4, metavar="N",
                   help="order of the position and parallel Butterworth filters (default 4)")
    g.add_argument("--causal", action="store_true",
                   help="filter forwards only (default: zero-phase, forwards and backwards)")
    g.add_argument("--differentiation", choices=("second-difference", "central-twice"),
                   default="second-difference", help="acceleration: second difference of the "
                   "position, or central difference of the central-difference velocity")
    g.add_argument("--decimate", type=int, default=1, metavar="N",
                   help="decimate columns and force by N (8th-order Chebyshev, zero-phase)")
    g.add_argument("--offset", action="store_true", help="a constant-force column (force_offset)")
    g.add_argument("--no-stiffness", action="store_true", help="no position column")
    g.add_argument("--edge-samples", type=int, default=200, metavar="N",
                   help="samples dropped at each end before decimating (default 200)")
    g.add_argument("--force-at", choices=("edge", "sample"), default="edge",
                   help="force at a sample: the two held inputs around it averaged (edge), or "
                   "the recorded u[k] (sample)")
    g.add_argument("--validate", metavar="FILE",
                   help="record for the cross-test: its force error under the fitted model, "
                   "processed the same way")
    s = p.add_argument_group("simulation-error options (--criterion simulation)")
    s.add_argument("--criterion", choices=("equation", "simulation"), default="equation",
                   help="equation: the force (IDIM-LS) fit alone (default); simulation: then "
                   "fit the parameters to the open-loop simulation error of the position, "
                   "from several starts (writes model.json)")
    s.add_argument("--model", metavar="FILE", help="the structure to fit (a model file, "
                   "lip.json or diagnosis.json) and one start (default: the force fit's)")
    s.add_argument("--hold", metavar="NAMES", help="parameters kept at the force fit's value "
                   "(the model file's where the force fit has none), e.g. mass")
    s.add_argument("--starts", type=int, metavar="N", help="perturbed starts beside the force "
                   "fit and the model file (default 2)")
    s.add_argument("--seed", type=int, metavar="S", help="seed of the perturbed starts "
                   "(default 0)")
    s.add_argument("--init-samples", type=int, metavar="N", help="output samples the initial "
                   "state is taken from (default 20: a parabola through them)")


def simulation(p: argparse.ArgumentParser) -> None:
    """``simulate``'s options after the model and the record, on the argparse parser ``p``."""
    p.add_argument("--init-samples", type=int, default=20, metavar="N",
                   help="output samples the initial state is taken from (default 20, "
                   "the benchmark protocol's); scores start after them")
    p.add_argument("--substeps", type=int, metavar="N",
                   help="integration sub-steps per sample (default: the model plant's)")
    p.add_argument("--closed-loop", action="store_true",
                   help="the machine's twin: the model file's controller on the record's "
                   "reference; predicts position and input")
    p.add_argument("--out", help="output folder (default results/simulate/<data name>)")


def export_ff(p: argparse.ArgumentParser) -> None:
    """``export-ff``'s model, target and options (docs/export.md)."""
    p.add_argument("model", help="params/lip.json or params/<row>_seed<k>.pt of a run, "
                   "identify's lip.json, or a diagnosis.json")
    p.add_argument("--to", required=True, help="c or onnx")
    p.add_argument("--out", required=True, help="output folder (replaced as a whole)")
    p.add_argument("--ts", type=seconds, help="sample time (s), where the file carries none")
    p.add_argument("--filter-tail", type=float, metavar="TOL",
                   help="PGNN: cut the feature filter where its discarded tail is below TOL of "
                        "its sum (default 1e-15, exact to rounding; larger: a shorter window "
                        "and look-ahead, less exact; see docs/export.md)")
    p.add_argument("--prefix", help="names of the public symbols, macros and files "
                   "(default clm_ff; two exports with different prefixes link together)")
    p.add_argument("--max-force", type=float, metavar="N",
                   help="C: |force| limit (N; default: the training data's, widened 50 %%)")
    p.add_argument("--max-velocity", type=float, metavar="M_PER_S",
                   help="C: |velocity| the model reads (m/s; default: the training data's, "
                        "widened 50 %%)")
    p.add_argument("--max-acceleration", type=float, metavar="M_PER_S2",
                   help="C: |acceleration| the model reads (m/s2; default as --max-velocity)")
    p.add_argument("--position-range", type=float, nargs=2, metavar=("LOW", "HIGH"),
                   help="C: positions accepted (m; default: the training data's range, widened "
                        "by half of it at each end)")
    p.add_argument("--limits-from", metavar="RECORD",
                   help="C: the record the model was fitted on, for the default limits (default: "
                        "the one the model's files name)")
    p.add_argument("--no-limits", action="store_true",
                   help="C: no force, velocity, acceleration or position limits")
    p.add_argument("--max-slew", type=float, metavar="N_PER_S",
                   help="C: the stream's rate limit (N/s; none by default; changeable at run "
                        "time)")
    p.add_argument("--count-m", type=float, metavar="M",
                   help="C, float build (-DCLM_FF_FLOAT): one count of its int64 fixed-point "
                        "reference, m (default 1e-12)")
    p.add_argument("--onnx-form", default="window", metavar="FORM",
                   help="ONNX: window (input the reference window, default) or mlp (input the "
                        "filtered features, MatMul/Add/Tanh only, for runtimes that accept only "
                        "plain MLPs)")

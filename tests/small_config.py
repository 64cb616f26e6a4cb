"""Short configs for tests that run the whole pipeline: two references of about 2 s and one
training pass; feedback only and the LIP (a few seconds per run), or a tiny mechanism study."""

SMALL_CONFIG = """\
name: small
seed: 1
references:
  r1: {points_m: [0.0, 0.01, -0.01, 0.0], dwell_s: 0.05}
  r2: {points_m: [0.0, 0.02, 0.0], dwell_s: 0.05}
training: {repeats: 1}
feedforwards:
  - kind: none
  - kind: lip
"""


def tiny_mechanism(records: int = 2, draws: int = 1, cases: str = "") -> str:
    """A mechanism study of ``records`` records x ``draws`` draws of a 3-neuron network, 5 LM
    iterations a fit, on the short references; ``cases``: its ``cases:`` block (YAML, indented
    under ``mechanism:``), else the config's default cases."""
    return ("name: m\nseed: 1\n"
            "references:\n"
            "  r1: {points_m: [0.0, 0.01, -0.01, 0.0], dwell_s: 0.05}\n"
            "  r2: {points_m: [0.0, 0.02, 0.0], dwell_s: 0.05}\n"
            "training: {repeats: 1}\n"
            f"mechanism:\n  records: {records}\n  draws: {draws}\n  hidden: 3\n"
            "  bootstrap: 200\n"
            "  pgnn: {weight_decay: 0, continuation_lambda: 0, max_iter: 5}\n" + cases)

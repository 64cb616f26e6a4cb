"""A short experiment config for tests that run the whole pipeline: two references of about 2 s
and one training pass, feedback only and the LIP (a few seconds per run)."""

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

"""CPU time and fingerprints of every record the tests make with the reference simulator.

The records are those of tests/test_foreign_records.py (every hidden effect and cell a test asks
for, the validation records, the prefixes compared with ``solve_ivp``), tests/test_simulate.py
and tests/test_emps_benchmark_cycles.py. For each record: the samples, the CPU time of
``run_loop`` and the sha256 of its ``y``, ``u`` and ``x`` arrays (their bytes). ``--save FILE``
stores the fingerprints as JSON, ``--check FILE`` compares with stored ones (exit 1 on any
difference): a change of the simulator that must not change its records is checked by saving
before and checking after. Fingerprints hold on one machine (libm's exp, tanh and sin may differ
in their last bit on another). Run from the repository root::

    python benchmarks/bench_reference_sim.py --save /tmp/ref.json      # before
    python benchmarks/bench_reference_sim.py --check /tmp/ref.json     # after

``--samples N`` makes only the first N samples of each record (a quick check: the loop is
causal, so a prefix is the same with and without the rest); ``--only TEXT`` the records whose
name contains TEXT.
"""

from __future__ import annotations

import argparse
import hashlib
import json
import math
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests"))

import reference_sim as ref  # noqa: E402
import test_foreign_records as tfr  # noqa: E402

TS = 1e-3  # test_simulate.py's and test_emps_benchmark_cycles.py's sample time (s)
RES = 1e-7  # m, their encoder


def _foreign():
    """(name, thunk(samples)) of test_foreign_records.py's records, as its tests ask for them."""
    cells = {**tfr.CELLS, **tfr.SEED_CELLS}
    pairs = [("none", c) for c in cells] + [("lugre", c) for c in tfr.CELLS]
    pairs += [("cable", c) for c in tfr.CELLS]
    pairs += [(h, c) for h in ("cogging", "offset") for c in ("pp1", "long1")]
    pairs += [("peak", "pp1"), ("peak", "long1"), ("dip", "pp1"), ("dip", "long1"),
              ("dip", "coarse1")]
    pairs += [("offset_cogging", c) for c in ("pp1", "long1", "emps1")]
    pairs += [("lugre_damped", c) for c in ("pp1", "long1", "emps1", "coarse1")]
    for hidden, cell in pairs:
        yield (f"foreign/{hidden}/{cell}",
               lambda n, h=hidden, c=cell: tfr.simulate_cell(tfr.STAGES[h], **cells[c],
                                                             samples=n)[0])
    stage = tfr.STAGES["cogging"]
    for homed_at in (0.0, 0.0013):  # test_validation_record_homed_elsewhere_is_registered
        moved = ref.Stage(**dict(stage.__dict__, cogging_phase=stage.cogging_phase
                                 + 2 * math.pi * homed_at / stage.cogging_period))
        yield (f"foreign/validation-homed-{homed_at}/pp1",
               lambda n, s=moved: tfr.simulate_cell(s, **dict(tfr.CELLS["pp1"], seed=7),
                                                    samples=n)[0])
    for hidden in ("lugre_damped", "cable"):  # test_the_reference_integrator_is_scipys_rk45
        def thunk(n, h=hidden):
            pairs = [m for d, v in tfr.SHORT for m in ((d, v), (0.0, v))]
            r = ref.trapezoid_reference(1e-3, moves=pairs, dwell=0.1)[:800][:n]
            return ref.run_loop(tfr.STAGES[h], ref.Cascade(60.0, 4700.0, 1e-3), r, 1e-3,
                                resolution=1e-7, dither_std=20.0, seed=1)
        yield f"foreign/solve_ivp-check/{hidden}", thunk


def _cascade(name, moves, *, stage=None, dither=5.0, seed=3):
    stage = stage or ref.Stage(mass=18.8, viscous=172.0, coulomb=7.21)

    def thunk(n):
        r = ref.trapezoid_reference(TS, moves=moves, accel=1.0, dwell=0.1)[:n]
        return ref.run_loop(stage, ref.Cascade(kp=160.0, kv=1700.0, ts=TS), r, TS,
                            resolution=RES, dither_std=dither, seed=seed)
    return name, thunk


def _others():
    """test_simulate.py's and test_emps_benchmark_cycles.py's records."""
    four = [(0.05, 0.1), (0.0, 0.05), (0.08, 0.15), (0.02, 0.02)]
    yield _cascade("simulate/record", four)
    yield _cascade("simulate/twin", [(0.03, 0.1), (0.0, 0.05)], dither=0.0)
    for s in (5, 6):
        yield _cascade(f"simulate/diagnosis-seed{s}", [(0.05, 0.1), (0.0, 0.05), (0.04, 0.02)],
                       stage=ref.Stage(mass=18.8, viscous=172.0, coulomb=7.21, offset=3.0),
                       seed=s)
    yield _cascade("simulate/candidates", [(0.1, 0.1), (0.0, 0.05), (0.1, 0.15), (0.0, 0.08)] * 3,
                   seed=4)
    for k, s in ((1.15, 7), (1.30, 8)):
        yield _cascade(f"simulate/drift-{k}", four * 2, seed=s,
                       stage=ref.Stage(mass=18.8, viscous=172.0 * k, coulomb=7.21, offset=3.0))
    cycle = [(0.05, 0.05), (0.1, 0.1), (0.05, 0.08), (0.0, 0.04)]
    yield _cascade("cycles/record", cycle * 3)
    plateaus = [(0.04, 0.04), (0.08, 0.08), (0.14, 0.12), (0.10, 0.06), (0.06, 0.1), (0.0, 0.03)]
    for viscous, s in ((172.0, 5), (190.0, 6)):
        yield _cascade(f"cycles/plateaus-{viscous}", plateaus, dither=0.5, seed=s,
                       stage=ref.Stage(mass=18.8, viscous=viscous, coulomb=7.21))
    yield _cascade("cycles/plateaus-stribeck", plateaus, dither=0.5, seed=7,
                   stage=ref.Stage(mass=18.8, viscous=172.0, coulomb=7.21, stribeck_peak=3.0,
                                   stribeck_velocity=0.05))


def fingerprint(rec) -> str:
    h = hashlib.sha256()
    for a in (rec.y, rec.u, rec.x):
        h.update(a.tobytes())
    return h.hexdigest()


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--samples", type=int, default=None, help="only the first N of each record")
    p.add_argument("--only", default="", help="the records whose name contains this")
    p.add_argument("--save", type=Path, help="store the fingerprints here (JSON)")
    p.add_argument("--check", type=Path, help="compare with fingerprints stored by --save")
    args = p.parse_args(argv)
    stored = json.loads(args.check.read_text()) if args.check else {"samples": args.samples}
    if stored["samples"] != args.samples:
        p.error(f"{args.check} holds records of --samples {stored['samples']}")
    stored = stored.get("records", {})
    out, total, bad = {}, 0.0, []
    for name, thunk in [*_foreign(), *_others()]:
        if args.only not in name:
            continue
        t0 = time.process_time()
        rec = thunk(args.samples)
        cpu = time.process_time() - t0
        total += cpu
        out[name] = fp = fingerprint(rec)
        verdict = ""
        if args.check:
            verdict = "same" if stored.get(name) == fp else "DIFFERENT"
            if verdict != "same":
                bad.append(name)
        print(f"{name:42s} {len(rec.y):6d} samples {cpu:7.2f} s CPU  {fp[:12]} {verdict}",
              flush=True)
    print(f"{len(out)} records, {total:.1f} s CPU in run_loop")
    if args.save:
        args.save.write_text(json.dumps({"samples": args.samples, "records": out}, indent=1))
    if args.check:
        print(f"{len(out) - len(bad)} of {len(out)} the same as {args.check}"
              + (f"; different: {', '.join(bad)}" if bad else ""))
    return 1 if bad else 0


if __name__ == "__main__":
    sys.exit(main())

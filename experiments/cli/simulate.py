"""``clm-sim simulate MODEL RECORD``: read the model file and the record, refuse what cannot run,
simulate (:mod:`experiments.records.simulation`) and write the folder."""

from __future__ import annotations

from pathlib import Path

from clm_sim.errors import UserError
from experiments.model_files import load_model
from experiments.records.simulation import simulate_record, twin_record, write, write_twin


def command(args, *, load) -> int:
    """``clm-sim simulate`` on the parsed ``args``; ``load(path, args)`` reads a record."""
    from clm_sim.outdir import check_output_folder

    out = Path(args.out) if args.out else Path("results") / "simulate" / Path(args.data).stem
    check_output_folder(out, what="a simulation",  # before the work
                        inputs=(args.model, args.data))
    try:
        run = load(args.data, args)
    except UserError as exc:
        if "(signal u)" in str(exc):
            raise UserError(f"{args.data}: no input column to drive the model with "
                            f"({str(exc).split(': ', 1)[1]}); name it with --columns u=NAME") \
                from None
        raise
    # A file without a rate (a shipped experiment config, whose PID is designed at the rate it
    # runs at) runs at the record's, as in diagnose; a file with one refuses another.
    model = load_model(args.model, run.ts)  # a file without ts runs at the record's
    if args.closed_loop:
        if model.controller is None:
            raise UserError(f"{args.model}: no controller in the model file; --closed-loop needs "
                            f"one ('controller:' in a model YAML)")
        twin = twin_record(model, run, source=str(args.data))
        write_twin(twin, out)
        print(twin.summary())
        print(f"wrote {out}/ (twin.csv, twin.npz, scores.json, figures/twin.png)")
        return 0
    sim = simulate_record(model, run, init_samples=args.init_samples, source=str(args.data),
                          substeps=args.substeps)
    write(sim, out)
    print(sim.summary())
    print(f"wrote {out}/ (simulation.csv, simulation.npz, scores.json, figures/simulation.png)")
    return 0

"""The EMPS benchmark study: physical models fitted by simulation error on the EMPS records, their
cycles, plateaus and drift, and the PGNN seeds that run away."""

KIND, SECTION = "emps_benchmark", "benchmark"  # the config's kind: and its settings' section


def study():
    """The study (:class:`experiments.studies.protocol.Study`), its module imported now."""
    from experiments.studies.emps.benchmark import STUDY

    return STUDY

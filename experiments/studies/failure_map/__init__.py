"""The failure map of lambda = 0: its settings, result type and figures."""

KIND, SECTION = "failure_map", "failure_map"  # the config's kind: and its settings' section


def study():
    """The study (:class:`experiments.studies.protocol.Study`), its module imported now."""
    from experiments.studies.failure_map.study import STUDY

    return STUDY

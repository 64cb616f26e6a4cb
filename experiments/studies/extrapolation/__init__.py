"""The extrapolation (lambda) study: its settings, result type and figures."""

KIND, SECTION = "extrapolation", "study"  # the config's kind: and its settings' section


def study():
    """The study (:class:`experiments.studies.protocol.Study`), its module imported now."""
    from experiments.studies.extrapolation.study import STUDY

    return STUDY

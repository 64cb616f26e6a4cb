"""Finding (iii) over training records and its mechanism: the study, the hidden units one by
one, and the prediction written before a run."""

KIND, SECTION = "mechanism", "mechanism"  # the config's kind: and its settings' section


def study():
    """The study (:class:`experiments.studies.protocol.Study`), its module imported now."""
    from experiments.studies.mechanism.study import STUDY

    return STUDY

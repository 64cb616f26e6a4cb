"""The identifiability study: converged profiles of the data cost at lambda = 0, their result
types and report."""

KIND, SECTION = "identifiability", "identifiability"  # the config's kind: and its settings' section


def study():
    """The study (:class:`experiments.studies.protocol.Study`), its module imported now."""
    from experiments.studies.profiles.study import STUDY

    return STUDY

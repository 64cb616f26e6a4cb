"""This package's study kind, as ``clm-sim study`` finds it (:mod:`experiments.studies.runner`
walks the study packages for this module): the config's ``kind:``, the section of its
settings, and the study, imported only when a config names it."""

KIND, SECTION = "identifiability", "identifiability"  # the config's kind: and its settings' section


def study():
    """The study (:class:`experiments.studies.protocol.Study`), its module imported now."""
    from experiments.studies.profiles.study import STUDY

    return STUDY

"""A logged run's files (the run itself is :class:`clm_sim.run.Run`).

* :mod:`~clm_sim.records.read`: :func:`~clm_sim.records.read.load_record`, a measured or
  simulated record mapped to the signals, scaled to SI units and checked;
* :mod:`~clm_sim.records.files`: a file's variables, whatever its format (CSV, NPZ, ``.mat``);
* :mod:`~clm_sim.records.checks`: the checks of the signals (numbers, time stamps, units);
* :mod:`~clm_sim.records.write`: NPZ, CSV and ``.mat`` files of a run, and ``clm-sim export``.
"""

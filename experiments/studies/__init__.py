"""Studies built on the testbed, one package each (its settings, compute, result types, report
and figures): extrapolation, failure_map, emps, mechanism, profiles; ``kinds`` reads which
one a study config is."""

"""The EMPS benchmark study: physical models fitted by simulation error on the EMPS records, their
cycles, plateaus and drift, and the PGNN seeds that run away."""

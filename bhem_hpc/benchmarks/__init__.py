"""Benchmarks: commands that print and pages that show what the solver costs.

- :mod:`~bhem_hpc.benchmarks.timing`: one Newton iteration on N x N sheets, time steps of a scene,
  ray tracing (``bhem-hpc bench``).
- :mod:`~bhem_hpc.benchmarks.performance`: the page ``docs/performance.md`` (``bhem-hpc bench --docs``).
- :mod:`~bhem_hpc.benchmarks.scaling`: strong and weak scaling, each case in its own ``mpirun``
  (``bhem-hpc bench --scaling``).
"""

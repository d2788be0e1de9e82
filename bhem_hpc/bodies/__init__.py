"""Several bodies in one global state.

- :mod:`~bhem_hpc.bodies.layout`: where each body's entries sit in the stacked vector (numpy only).
- :mod:`~bhem_hpc.bodies.petsc`: :class:`~bhem_hpc.bodies.petsc.StackedProblem`, the bodies'
  problems and the contributions that couple them as one problem (PETSc).
"""

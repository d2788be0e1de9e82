"""Several bodies in one global state.

- :mod:`~bhem_hpc.bodies.layout`: where each body's entries sit in the stacked vector (numpy only).
- :mod:`~bhem_hpc.bodies.petsc`: :class:`~bhem_hpc.bodies.petsc.StackedProblem`, the bodies'
  problems (shells' and solids') and the contributions that couple them as one problem (PETSc).
- :mod:`~bhem_hpc.bodies.shared_dofs`: the control points that patches share along conforming
  interfaces (numpy only); :mod:`~bhem_hpc.bodies.shared_petsc`: the stacked problem reduced to
  one unknown per shared group (PETSc).
- :mod:`~bhem_hpc.bodies.body`: the :class:`~bhem_hpc.bodies.body.Body` protocol and the shell body;
  :mod:`~bhem_hpc.bodies.solid`: the solid body and its model built from its scene table.
- :mod:`~bhem_hpc.bodies.run`: a run of a scene of several bodies.
"""

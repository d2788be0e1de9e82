"""Solids bounded by NURBS parts: the Shape Matching Element Method (Trusty, Chen, Levin 2021).

Numpy and scipy: the ray-cast volume quadrature (:mod:`.quadrature`), boundary samples
(:mod:`.sampling`), ray-cast blending weights (:mod:`.blending`), deformation origins by network
flow (:mod:`.origins`), shape matching (:mod:`.shape_matching`), hyperelastic
densities (:mod:`.elasticity`) and the solid that joins them (:mod:`.sem`), with serial solves
(:mod:`.equilibrium`). The solid as a body of the Newton driver: :mod:`.model` (mpi4py) and its
PETSc problem, :mod:`.petsc`.
"""

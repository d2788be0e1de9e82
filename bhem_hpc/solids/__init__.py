"""Solids bounded by NURBS parts: the Shape Matching Element Method (Trusty, Chen, Levin 2021).

Numpy and scipy only: the ray-cast volume quadrature (:mod:`.quadrature`), boundary samples
(:mod:`.sampling`), ray-cast blending weights (:mod:`.blending`), deformation origins by network
flow (:mod:`.origins`), shape matching (:mod:`.shape_matching`), hyperelastic
densities (:mod:`.elasticity`) and the solid that joins them (:mod:`.sem`).
"""

"""Solids bounded by NURBS parts: the Shape Matching Element Method (Trusty, Chen, Levin 2021).

:mod:`.quadrature` holds the ray-cast volume quadrature (numpy only).
"""

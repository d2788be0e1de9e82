"""Parametric surfaces, numpy only: bicubic Hermite patches, shapes, evaluation and surface files.

:mod:`.surface` holds the parameter grid and the Hermite surface (nodal data, evaluation, Bézier
control points, tessellation, ``.npz`` files); :mod:`.hermite` the 1-D cubic Hermite basis.
"""

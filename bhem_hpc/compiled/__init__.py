"""Compiled (numba) versions of the geometry package's ray queries on rational Bezier patches, for the
setup stages of solids; the numpy functions of :mod:`bhem_hpc.geometry` are their reference."""

"""bhem-hpc: thin shells with C1 bicubic Hermite elements on FEniCSx and PETSc.

Importing the package changes nothing in the process; the command line picks OpenBLAS's kernels
(:func:`bhem_hpc.blas.use_best_kernels`) before numpy loads it, and scripts can do the same.
"""

__version__ = "0.1.0"

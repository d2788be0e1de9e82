"""bhem-hpc: thin shells with C1 bicubic Hermite elements on FEniCSx and PETSc."""

__version__ = "0.1.0"

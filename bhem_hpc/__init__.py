"""bhem-hpc: thin shells with C1 bicubic Hermite elements on FEniCSx and PETSc."""

from bhem_hpc.blas import choose_openblas_kernels, warn_about_generic_kernels

__version__ = "0.1.0"

# Before numpy or PETSc load OpenBLAS: it reads its kernel choice once (see bhem_hpc.blas).
warn_about_generic_kernels(choose_openblas_kernels())

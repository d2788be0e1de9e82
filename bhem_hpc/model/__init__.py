"""The shell model: material, boundary conditions, loads and the compiled energy forms (no PETSc)."""

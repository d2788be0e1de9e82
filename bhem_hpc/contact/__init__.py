"""Contact between time steps (paper §6.2): detection (numpy), the response and its PETSc projector.

Nothing is imported here: a scene without contact effects never loads this package's modules.
"""

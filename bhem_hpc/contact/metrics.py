"""The contact methods and the metrics of the impulse response (no imports: the scene parser reads them).

``"impulse"``: contact resolved between time steps by impulses and a push-out
(:mod:`bhem_hpc.contact.response`); ``"ipc"``: ipc-toolkit's barrier inside the Newton solve, with
a collision-free step bound (:mod:`bhem_hpc.contact.ipc_contribution`).


``"mass"``: the impulses are measured in the mass matrix plus the stiffness damping (M + S);
``"jacobian"``: in the step's Jacobian (dt^2 J + S). See :class:`~bhem_hpc.contact.response.ContactSettings`.
"""

CONTACT_METRICS = ("mass", "jacobian")
CONTACT_METHODS = ("impulse", "ipc")
#: ``effects.contact.collision_cells``: collision-lattice cells per patch side (IPC).
COLLISION_CELLS_RANGE = (1, 16)

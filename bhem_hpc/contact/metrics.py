"""The metrics of the contact response's impulses (no imports: the scene parser reads them).

``"mass"``: the impulses are measured in the mass matrix plus the stiffness damping (M + S);
``"jacobian"``: in the step's Jacobian (dt^2 J + S). See :class:`~bhem_hpc.contact.response.ContactSettings`.
"""

CONTACT_METRICS = ("mass", "jacobian")

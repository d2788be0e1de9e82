"""Contact between time steps (paper §6.2).

Detection, numpy only: :mod:`.detection` (the detector and its colliders), :mod:`.samples`,
:mod:`.broad_phase`, :mod:`.closest_points`, :mod:`.collider_contacts`, :mod:`.self_contact`, and
the contact record :mod:`.contacts`. Response: :mod:`.response` (rounds of detection, impulses,
friction, push-out) and its PETSc projector :mod:`.petsc`.

Nothing is imported here: a scene without contact effects never loads this package's modules.
"""

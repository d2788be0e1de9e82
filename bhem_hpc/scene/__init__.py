"""Scene files (TOML): parsing and validation, before anything is built (numpy + stdlib only).

Every error names the file, the key and what was expected. The format is documented in
README.md ("Scene files"); :func:`load_scene` returns a :class:`Scene` whose parts map one to one
onto the library's objects (surface, :class:`~bhem_hpc.model.material.Material`, constraints with
motions, :class:`~bhem_hpc.model.shell.Loads`-like effects, time, solver and output settings).

Each kind of table parses itself and registers itself by name (pbrt-v4's ``Create``): surface
kinds in :data:`~.surfaces.SURFACES`, motion types in :data:`~.motions.MOTIONS`, collider types in
:data:`~.colliders.COLLIDERS`, constraint types in :data:`~.constraints.CONSTRAINTS`, load families in
:data:`~.loads.LOADS`, body types in :data:`~.bodies.BODY_TYPES`; :mod:`.table` gives them typed
access with errors that name the key.
"""

# isort: off
from bhem_hpc.scene.loader import load_scene  # registers the shell body type, the default, first

from bhem_hpc.scene import solids as _solids  # noqa: F401  (registers the solid body type)
from bhem_hpc.scene import cad_shell as _cad_shell  # noqa: F401  (registers the cad_shell body type)

# isort: on
from bhem_hpc.scene.records import Effects, Motion, Scene, SceneConstraint, SceneContact, ScenePoint
from bhem_hpc.scene.table import SceneError

__all__ = ["Effects", "Motion", "Scene", "SceneConstraint", "SceneContact", "ScenePoint", "SceneError", "load_scene"]

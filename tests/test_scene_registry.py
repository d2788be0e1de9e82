"""Scene tables parse themselves by kind, through registries (pbrt-v4's Create)."""

from __future__ import annotations

import pytest

from bhem_hpc.scene import SceneError, load_scene
from bhem_hpc.scene.bodies import BODY_TYPES
from bhem_hpc.scene.colliders import COLLIDERS
from bhem_hpc.scene.constraints import CONSTRAINTS
from bhem_hpc.scene.interfaces import INTERFACE_TYPES
from bhem_hpc.scene.loads import LOADS
from bhem_hpc.scene.motions import MOTIONS
from bhem_hpc.scene.surfaces import SURFACES
from bhem_hpc.scene.table import Registry


def test_every_kind_is_registered_in_the_order_users_read():
    assert SURFACES.names == ("rectangle", "cylinder", "sphere_zone", "annulus_sector", "torus", "file", "mapped",
                             "cad_part")
    assert BODY_TYPES.names == ("shell", "solid", "cad_shell")
    assert INTERFACE_TYPES.names == ("joint", "seam")
    assert MOTIONS.names == ("linear", "rotation", "keyframes")
    assert COLLIDERS.names == ("plane", "sphere", "cylinder", "capsule", "needles", "mesh", "patches")
    assert CONSTRAINTS.names == ("clamp", "pin", "simply_supported", "hinged", "symmetry", "diaphragm", "fix")
    assert LOADS.names == ("point_loads", "line_loads", "area_loads", "edge_moments")


def test_a_kind_registered_twice_is_refused():
    registry = Registry("widget type")
    registry.register("knob")(lambda t: t)
    with pytest.raises(ValueError, match="widget type 'knob' is registered twice"):
        registry.register("knob")(lambda t: t)


def test_an_unknown_kind_names_the_registered_ones(shared_tmp_path, comm):
    scene = shared_tmp_path / "cone.toml"
    if comm.rank == 0:
        scene.write_text('[surface]\nkind = "cone"\n[material]\nyoung = 1e6\npoisson = 0.3\nthickness = 1e-3\n'
                         'density = 100.0\n[time]\ndt = 0.01\nduration = 0.01\n')  # fmt: skip
    comm.Barrier()
    with pytest.raises(SceneError, match=r"key 'surface.kind' must be one of \('rectangle', 'cylinder', "):
        load_scene(scene)

"""Irregular panels: a square of parameters mapped onto any outline (``kind = "mapped"``) is the
shell of that outline (its area and mass), and maps that are not panels are refused by key."""

from __future__ import annotations

import numpy as np
import pytest
from helpers import write_scene

from bhem_hpc.bodies.body import ShellBody
from bhem_hpc.run import build_model
from bhem_hpc.scene import SceneError, load_scene

PANEL = """
[surface]
kind = "mapped"
patches = [6, 4]
discretization = "{discretization}"
position = {position}
[material]
young = 2.0e6
poisson = 0.243
thickness = 3.18e-4
density = 472.6
[time]
dt = 0.01
steps = 1
"""
#: A trapezoid 0.5 m high, 0.6 m wide at the bottom and 0.3 m at the top (an A-line skirt's panel).
TRAPEZOID = '["(0.6 - 0.3 * xi2) * (xi1 - 0.5)", "0.5 * xi2", "0"]'


@pytest.mark.parametrize("discretization", ["hermite", "bspline2", "bspline3"])
def test_a_mapped_trapezoid_is_a_shell_of_its_outline(comm, shared_tmp_path, discretization):
    """The map is bilinear: every discretization holds it exactly, so the panel's mass is the
    trapezoid's area (0.225 m^2) times density and thickness to round-off, and its corners are the
    trapezoid's."""
    scene = load_scene(write_scene(comm, shared_tmp_path / "panel.toml",
                              PANEL.format(discretization=discretization, position=TRAPEZOID)))  # fmt: skip
    corners = scene.surface.evaluate(np.array([0.0, 1.0, 0.0, 1.0]), np.array([0.0, 0.0, 1.0, 1.0])).x
    np.testing.assert_allclose(corners, [[-0.3, 0, 0], [0.3, 0, 0], [-0.15, 0.5, 0], [0.15, 0.5, 0]], atol=1e-12)
    body = ShellBody("panel", 0, scene, build_model(scene, comm))
    assert body.mass() == pytest.approx(0.225 * 472.6 * 3.18e-4, rel=1e-12)


@pytest.mark.parametrize(
    ("position", "message"),
    [
        ('["xi1", "xi2"]', r"key 'surface.position' must be 3 expressions of xi1 and xi2 \(x, y, z\) \[m\]"),
        ('["xi1", "xi2", "import os"]', r"key 'surface.position' must be 3 expressions of xi1 and xi2 \("),
        ('["xi1", "1 / (xi2 - 0.5)", "0"]', r"key 'surface.position' must be 3 expressions finite on the whole square"),
        ('["xi1", "xi1", "0"]', r"table 'surface': the mapped panel is degenerate"),
    ],
)
def test_maps_that_are_not_panels_are_refused_naming_the_key(comm, shared_tmp_path, position, message):
    path = write_scene(comm, shared_tmp_path / "bad.toml", PANEL.format(discretization="hermite", position=position))
    with pytest.raises(SceneError, match=message):
        load_scene(path)

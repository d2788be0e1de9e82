"""Write the NURBS models the solid jobs read (jobs/models/*.igs), as a modeller would export them.

castle.igs: a base block, a keep and four round towers at the base's corners, overlapping
(16 parts, the castle of the SEM paper's Table 1 as bhem_hpc.studies.sem_models builds it).
tyre.igs: a torus tread in 16 rational Bezier pieces on a hub of revolution reaching into it
(17 parts, "tread 0".."tread 15" and "hub"; IGES keeps 8-character labels: "tread0", "hub").
toy.igs: the castle scaled to a 0.2 m toy 2 cm above the x-y plane (jobs/toy-on-cloth.toml,
jobs/cloth-over-castle.toml).
block.igs: a 0.2 m cube of six biquadratic faces (jobs/two-solids.toml).
hood.3dm: a car-hood-like panel, 1.2 m x 1 m crowned 6 cm, as four bicubic parts meeting along
x = 0 and y = 0 (jobs/hood.toml: one shell of four patches joined where the parts meet).
elbow.igs: a 90-degree pipe bend (bend radius 0.3 m, pipe radius 5 cm) revolved as modellers do, one
rational part only C0 at the tube circle's quarter points (jobs/pipe-elbow.toml).
Run: .venv/bin/python jobs/make_models.py  (the generated files are committed).
"""

from pathlib import Path

import numpy as np

from bhem_hpc.geometry import nurbs
from bhem_hpc.io.cad import write_parts
from bhem_hpc.studies.sem_models import castle, tyre

MODELS = Path(__file__).resolve().parent / "models"

if __name__ == "__main__":
    MODELS.mkdir(exist_ok=True)
    # the castle scaled from 1.24 m to 0.2 m, centred above the origin, its base 2 cm up
    scale = 0.2 / 1.24
    toy = [part.with_control(part.control * scale + [-0.5 * scale, -0.5 * scale, 0.02]) for part in castle()]
    block = nurbs.box_faces([-0.1, -0.1, -0.1], [0.1, 0.1, 0.1], degree=2)
    for name, parts in (("castle", castle()), ("tyre", tyre()), ("toy", toy), ("block", block)):
        write_parts(MODELS / f"{name}.igs", parts)
        print(f"wrote {MODELS / name}.igs")
    def crown_height(x, y):
        return 0.06 * (1 - (x / 0.6) ** 2) * (1 - (y / 0.5) ** 2) + 0.02 * np.sin(np.pi * x)

    crown = nurbs.graph_parts(crown_height, (-0.6, 0.6), (-0.5, 0.5), (2, 2))
    write_parts(MODELS / "hood.3dm", [part.with_name(f"hood {k}") for k, part in enumerate(crown)])
    print(f"wrote {MODELS / 'hood.3dm'}")
    write_parts(MODELS / "elbow.igs", [nurbs.pipe_bend(0.3, 0.05, (0.0, 0.5 * np.pi)).with_name("elbow")])
    print(f"wrote {MODELS / 'elbow.igs'}")

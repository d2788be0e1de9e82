"""Write the NURBS models the solid jobs read (jobs/models/*.igs), as a modeller would export them.

castle.igs: a base block, a keep and four round towers at the base's corners, overlapping
(16 parts, the castle of the SEM paper's Table 1 as bhem_hpc.studies.sem_models builds it).
Run: .venv/bin/python jobs/make_models.py  (the generated files are committed).
"""

from pathlib import Path

from bhem_hpc.io.cad import write_parts
from bhem_hpc.studies.sem_models import castle

MODELS = Path(__file__).resolve().parent / "models"

if __name__ == "__main__":
    MODELS.mkdir(exist_ok=True)
    write_parts(MODELS / "castle.igs", castle())
    print(f"wrote {MODELS / 'castle.igs'}")

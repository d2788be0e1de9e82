"""Every study by name."""

from __future__ import annotations

from bhem_hpc.studies import buckling, cantilever, drape, plate, wrinkle
from bhem_hpc.studies.study import Study

#: In the order of the accuracy-cost page.
STUDIES: dict[str, Study] = {m.STUDY.name: m.STUDY for m in (plate, buckling, drape, wrinkle, cantilever)}

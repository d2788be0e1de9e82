"""The SEM cantilever against the tetrahedral FEM reference dolfinx computes on the same beam (the
paper's Fig. 10; ``study`` marker: about three minutes)."""

from __future__ import annotations

import pytest

from bhem_hpc.studies.petsc import fem_tip_deflection
from bhem_hpc.studies.solids_page import BEAM, BEAM_MATERIAL, GRAVITY, cantilever_rows

pytestmark = pytest.mark.rank_free  # no communicator: the same computation on every rank


@pytest.mark.study
def test_cantilever_sag_converges_to_the_fem_reference():
    """Bicubic parts, quadratic matching, a fixed blending cutoff of 0.12 m: the relative error of
    the tip sag falls with every doubling of the sections, at first order or better at the fine end,
    and ends within 4 % at 16 sections (21.6, 13.0, 6.8, 2.7 % measured at 2, 4, 8, 16; the error
    energy of eq. 16, which ties every part to the blended volume, stiffens coarse beams). The 4 %
    allow for the reference's own error (0.4 % between 40 x 4 x 4 and 80 x 8 x 8 P2 boxes) and for
    the volume quadrature's lines through the section."""
    reference = fem_tip_deflection(BEAM, BEAM_MATERIAL, GRAVITY)
    rows = cantilever_rows((2, 4, 8, 16), cutoffs=({"alpha": 0.12},))
    errors = [abs(r["sag"] / reference - 1.0) for r in rows]
    assert errors[0] > errors[1] > errors[2] > errors[3]
    assert errors[3] < 0.6 * errors[2]
    assert errors[3] < 0.04

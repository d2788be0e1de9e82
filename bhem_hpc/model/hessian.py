"""The Hessian kinds a model's Jacobian can be built with (importable without dolfinx).

- ``"exact"``: the UFL derivative of the residual; indefinite wherever a membrane is compressed or
  a shell buckles, which is what statics and path following read their stability from.
- ``"pseudo"``: the BHEM paper's: bending drops the second derivative of its curvature strain.
- ``"projected"``: positive semi-definite for every term (bending as ``"pseudo"``, the membrane's
  geometric stiffness from the tensile part of its stress only), so that every Newton step of an
  incremental potential goes downhill.
- ``"adaptive"``: the membrane's compressive stress is dropped only from its stiffness out of the
  plane (where it makes cloth wrinkle) and kept in the plane; where that Hessian's LDL^T still has
  negative pivots (in-plane compression of order one), the step is recomputed with the projected
  one. Descent steps as ``"projected"``, in far fewer Newton iterations on compressed cloth (cotton
  hanging from moving corners, 25 x 25 Hermite patches, the sheet in its plane: 7.6 per step against
  32 for ``"projected"``, whose linear convergence when the corners stop needed dt halvings); the
  default for time steps. Where wrinkles grow out of the plane, both still converge linearly.
  The iterative linear path, whose Krylov solves tell no inertia, takes ``"projected"`` instead.
"""

from __future__ import annotations

from typing import Literal

HessianKind = Literal["exact", "pseudo", "projected", "adaptive"]
HESSIAN_KINDS: tuple[str, ...] = ("exact", "pseudo", "projected", "adaptive")

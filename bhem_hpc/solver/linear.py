"""Which linear solver a Newton iteration uses: MUMPS' direct factorization or a Krylov method.

No PETSc here: the choice depends on the problem's size, on how mass-dominated the time step's
matrix is and on the memory a factorization would take, all known before anything is assembled,
and on every rank alike.

* ``"direct"``: MUMPS LDL^T (LU for non-symmetric Jacobians). Robust for any matrix, statics
  and buckling included; its factor grows like DoFs log DoFs in memory and DoFs^1.5 in flops.
* ``"iterative"``: Krylov solves. A time step's matrix ``M / dt^2 + K`` goes to flexible GMRES
  preconditioned by incomplete factorizations (ILU(0) on the 3 x 3 blocks) of each rank's rows
  grown by one layer of the neighbouring ranks' rows, combined by restricted additive Schwarz: the
  inertia keeps the matrix well conditioned, so a few iterations suffice (``bhem-hpc bench
  --scaling`` reports them), and on the paper's cloth this took less time per solve than Jacobi,
  GAMG (rigid-body-free, threshold 0.01) or BoomerAMG, whose setup and cycles cost more than the
  iterations they save here. Without the overlap (block Jacobi: conjugate gradients could run, the
  preconditioner being symmetric) the coupling across rank boundaries is lost and the iterations
  per solve grow with the rank count; the restricted Schwarz preconditioner is not symmetric,
  hence flexible GMRES. A static stiffness ``K`` (no inertia, condition number ~ patches^4) gets
  GMRES with hypre's BoomerAMG (nodal coarsening): of the preconditioners tried its iteration count
  was the lowest and grows the least with the mesh, where incomplete factorizations need hundreds
  of iterations.
* ``"auto"``: iterative for dynamic problems of at least :data:`ITERATIVE_MIN_DOFS` DoFs whose
  step matrix is mass-dominated enough (:func:`mass_dominance` >= :data:`MIN_MASS_DOMINANCE`), and
  whenever a factorization would not fit in memory; direct otherwise.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from bhem_hpc.errors import UserError

LINEAR_SOLVERS = ("auto", "direct", "iterative")
#: Below this size a factorization (kept across Newton iterations and steps) costs less than Krylov
#: solves; above it the Krylov path takes about as long or less, in a fraction of the memory
#: (docs/scaling.md).
ITERATIVE_MIN_DOFS = 100_000
#: The inertia-to-membrane-stiffness ratio below which the preconditioned Krylov solves need too many
#: iterations.
MIN_MASS_DOMINANCE = 0.01
#: MUMPS' factor and work space per Jacobian nonzero, measured on Hermite cloth (AMF ordering) at
#: 11,532 DoFs, growing with log2 of the size (nested-dissection-like fill).
FACTOR_BYTES_PER_NONZERO = 30.0
FILL_GROWTH_PER_DOUBLING = 0.16
#: Memory left to everything else than the factor (meshes, forms, Jacobian, vectors).
MEMORY_HEADROOM = 0.75


class LinearSolverError(UserError, ValueError):
    """A linear solver that cannot be used for this problem (e.g. a factorization too large)."""


@dataclass(frozen=True)
class LinearSolverChoice:
    """The linear solver of a Newton solver and why.

    Attributes:
        kind: ``"direct"`` or ``"iterative"``.
        requested: what was asked for (``"auto"``, ``"direct"``, ``"iterative"``).
        reason: in words, for logs and ``summary.json``.
        mass_dominance: :func:`mass_dominance` of the step matrix (0 for statics).
        direct_bytes: estimated memory of a MUMPS factorization (all ranks together).
        available_bytes: memory available to the run (all nodes together).
    """

    kind: str
    requested: str
    reason: str
    mass_dominance: float
    direct_bytes: float
    available_bytes: float

    def as_dict(self) -> dict:
        return {
            "kind": self.kind,
            "requested": self.requested,
            "reason": self.reason,
            "mass_dominance": self.mass_dominance,
            "direct_gb_estimate": self.direct_bytes / 1e9,
            "available_gb": self.available_bytes / 1e9,
        }


def mass_dominance(density: float, young: float, poisson: float, element_size: float, time_step: float | None) -> float:
    """Inertia over membrane stiffness per unknown of a time step's matrix:
    ``rho l^2 (1 - nu^2) / (Y dt^2)`` for elements of size ``l`` (both scale with the thickness);
    0 without time stepping. Large: ``M / dt^2`` dominates and the matrix is well conditioned."""
    if time_step is None:
        return 0.0
    return density * element_size**2 * (1.0 - poisson**2) / (young * time_step**2)


def direct_factor_bytes(dofs: int, nonzeros: int) -> float:
    """Estimated memory of MUMPS' LDL^T factorization of a shell Jacobian (all ranks)."""
    doublings = math.log2(max(dofs / 11532, 1.0))
    return FACTOR_BYTES_PER_NONZERO * nonzeros * (1.0 + FILL_GROWTH_PER_DOUBLING * doublings)


def choose_linear_solver(
    requested: str, dofs: int, nonzeros: int, dominance: float, available_bytes: float, dynamic: bool
) -> LinearSolverChoice:
    """The linear solver for a problem (see the module's description of ``"auto"``).

    Raises:
        LinearSolverError: ``requested`` is unknown, or ``"direct"`` was asked for and the
            factorization would not fit in the available memory.
    """
    if requested not in LINEAR_SOLVERS:
        raise LinearSolverError(f"linear solver must be one of {LINEAR_SOLVERS}, got {requested!r}")
    need = direct_factor_bytes(dofs, nonzeros)
    fits = need <= MEMORY_HEADROOM * available_bytes
    common = (requested, dominance, need, available_bytes)
    memory = f"a factorization needs about {need / 1e9:.1f} GB, {available_bytes / 1e9:.1f} GB are available"
    if requested == "direct":
        if not fits:
            raise LinearSolverError(f"the direct solver cannot run: {memory}; use the iterative solver")
        return LinearSolverChoice("direct", requested, "requested", *common[1:])
    if requested == "iterative":
        return LinearSolverChoice("iterative", requested, "requested", *common[1:])
    if not fits:
        return LinearSolverChoice("iterative", requested, f"{memory}", *common[1:])
    if dynamic and dofs >= ITERATIVE_MIN_DOFS and dominance >= MIN_MASS_DOMINANCE:
        reason = f"{dofs} DoFs >= {ITERATIVE_MIN_DOFS} and mass dominance {dominance:.3g} >= {MIN_MASS_DOMINANCE}"
        return LinearSolverChoice("iterative", requested, reason, *common[1:])
    why = "a static problem" if not dynamic else (
        f"{dofs} DoFs < {ITERATIVE_MIN_DOFS}" if dofs < ITERATIVE_MIN_DOFS
        else f"mass dominance {dominance:.3g} < {MIN_MASS_DOMINANCE}"
    )  # fmt: skip
    return LinearSolverChoice("direct", requested, why, *common[1:])


def available_memory(comm) -> float:
    """Bytes the run can use: MemAvailable of each node (``/proc/meminfo``) summed over the nodes
    of ``comm`` (collective; infinite where unknown)."""
    node = comm.Split_type(split_type=_shared_memory_split(), key=comm.rank)
    try:
        local = 0.0
        if node.rank == 0:
            try:
                with open("/proc/meminfo") as f:
                    fields = dict(line.split(":", 1) for line in f)
                local = float(fields["MemAvailable"].split()[0]) * 1024
            except (OSError, KeyError, ValueError):
                local = math.inf  # unknown: no limit
        return float(comm.allreduce(local))
    finally:
        node.Free()


def _shared_memory_split() -> int:
    from mpi4py import MPI  # here, not at import: a scene imports this module without MPI

    return MPI.COMM_TYPE_SHARED

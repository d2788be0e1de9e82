"""A model's UFL terms as an energy contribution that dolfinx assembles (the PETSc side of
:mod:`.contributions`, whose numpy contributions work on arrays).

:class:`AssembledContribution` is what :class:`~bhem_hpc.solver.problem.ShellProblem` asks of a term
it assembles into PETSc objects directly: its share of the potential, its gradient added into the
open residual vector before the ghost exchange, and its Hessian (of a chosen kind) added into the
open matrix, whose sparsity it gives. :class:`ShellFormTerms` is a shell model's energies and loads
composed in UFL (:class:`~bhem_hpc.model.shell.ShellModel`): one such contribution.
"""

from __future__ import annotations

from typing import Protocol, runtime_checkable

import dolfinx.fem as fem
import dolfinx.fem.petsc as fem_petsc
from petsc4py import PETSc

from bhem_hpc.model.shell import ShellModel


@runtime_checkable
class AssembledContribution(Protocol):
    """An energy term assembled into PETSc objects (collective methods, called on every rank)."""

    name: str

    def create_matrix(self, matrix_type: str) -> PETSc.Mat:
        """An unassembled matrix of the open layout with this term's sparsity."""
        ...

    def create_vector(self) -> PETSc.Vec:
        """A vector of the open layout (with ghosts)."""
        ...

    def local_energy(self) -> float:
        """This rank's share of the term's potential at the current state."""
        ...

    def add_gradient(self, gradient: PETSc.Vec) -> None:
        """Add the gradient into ``gradient`` (open layout, before the ghost exchange)."""
        ...

    def add_hessian(self, matrix: PETSc.Mat, kind: str) -> None:
        """Add the Hessian of ``kind`` into ``matrix`` (open layout; not yet assembled)."""
        ...

    def hessian_kinds(self) -> tuple[str, ...]:
        """The Hessian kinds it can assemble, the one Newton iterates with first."""
        ...


class ShellFormTerms:
    """The UFL terms of a :class:`ShellModel` (membrane, bending, inertia, loads) as one contribution:
    its potential, residual and Jacobian forms of each Hessian kind.

    Args:
        model: the shell model whose forms are assembled.
    """

    name = "shell terms"

    def __init__(self, model: ShellModel):
        self.model = model

    def create_matrix(self, matrix_type: str) -> PETSc.Mat:
        return fem_petsc.create_matrix(self.model.jacobian_form, matrix_type)

    def create_vector(self) -> PETSc.Vec:
        return fem_petsc.create_vector(self.model.residual_form)

    def local_energy(self) -> float:
        return fem.assemble_scalar(self.model.potential_form)

    def add_gradient(self, gradient: PETSc.Vec) -> None:
        fem_petsc.assemble_vector(gradient, self.model.residual_form)

    def add_hessian(self, matrix: PETSc.Mat, kind: str) -> None:
        fem_petsc.assemble_matrix(matrix, self.model.jacobian_forms[kind])

    def hessian_kinds(self) -> tuple[str, ...]:
        return tuple(self.model.jacobian_forms)

    def term_gradient_forms(self) -> dict[str, fem.Form]:
        """The residual form of each of the model's terms by name (to tell which dominates)."""
        return self.model.term_residual_forms()

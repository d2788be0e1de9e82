"""Contact response between time steps (paper §6.2): detection rounds, impulses, friction, push-out.

After the SNES solve of a step has moved the shell from ``x_n`` to a candidate ``x*`` with velocity
``v* = (x* - x_n) / dt``, :meth:`ContactHandler.respond` runs rounds of

1. detection (:mod:`bhem_hpc.contact.detection`) of every contact of the straight-line motion
   ``x_n -> x*`` within the push-out distance - simultaneous contacts together, the earliest time
   of impact recorded;
2. the velocity update: zero restitution, i.e. the normal velocity of every approaching contact
   point relative to its obstacle becomes 0 (separating points keep theirs); with friction the
   tangential velocity is reduced by ``mu`` times the normal velocity change, Coulomb's cone
   [Bridson et al. 2002], as rows solved together with the normal rows. Rows are met in least
   squares in the metric ``W`` (:class:`~bhem_hpc.contact.petsc.ContactProjector`, in dual form):
   ``M + S`` by default, factored once for the run, or ``dt^2 J + S`` (``metric = "jacobian"``),
   refactored each step with contact; impulses only push (a linear complementarity problem,
   :func:`bhem_hpc.collision.lcp.solve_lcp`);
3. the position update: positions restart from ``x_n`` with the new velocity - each contact point's
   motion is rolled back to its collision moment and continues with the post-impulse velocity -
   and every contact point is pushed out to the push-out distance (linear position rows, the same
   factorization of W).

A round that finds nothing closer than half the push-out distance ends the loop (at most
``max_rounds``). Every rank tests an interleaved share of the samples and the contact list is
gathered, so all ranks build the same rows and the result equals the serial one.
"""

from __future__ import annotations

import logging
import math
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass

import numpy as np
from mpi4py import MPI

from bhem_hpc.contact.bodies import BodiesDetector, ShellContactSurface, StackedEntries
from bhem_hpc.contact.bodies_petsc import StackedProjector
from bhem_hpc.contact.contacts import Contacts
from bhem_hpc.contact.detection import ContactDetector
from bhem_hpc.contact.metrics import CONTACT_METRICS
from bhem_hpc.contact.petsc import ContactProjector
from bhem_hpc.errors import InputError
from bhem_hpc.model.shell import ShellModel
from bhem_hpc.solver.problem import ShellProblem
from bhem_hpc.solver.state import StateCorrection

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class ContactSettings:
    """Parameters of the response (sampling and self-collision belong to the
    :class:`~bhem_hpc.contact.detection.ContactDetector`).

    Attributes:
        push_out: distance every contact point is pushed out to [m].
        max_rounds: bound on the detection-response rounds of a step.
        metric: the metric ``W`` that distributes impulses and pushes over the nodal DOFs.
            ``"mass"``: ``M + S`` (momentum-based impulses, as the paper's [HVTG08]; factored once
            for the run, through its scalar block). ``"jacobian"``: ``dt^2 J + S`` with the step's
            Jacobian (the implicit step's answer to an impulse: a stiff shell moves as a whole;
            refactored every step with contact).
    """

    push_out: float = 1e-4
    max_rounds: int = 4
    metric: str = "mass"

    def validate(self) -> None:
        if self.metric not in CONTACT_METRICS:
            raise InputError(f"contact metric must be one of {CONTACT_METRICS}, got {self.metric!r}")
        if not (math.isfinite(self.push_out) and self.push_out > 0):
            raise InputError(f"contact push_out must be a finite number > 0, got {self.push_out!r}")
        if not (isinstance(self.max_rounds, int) and self.max_rounds >= 1):
            raise InputError(f"contact max_rounds must be an integer >= 1, got {self.max_rounds!r}")


@dataclass
class ContactReport:
    """What the contact response did in one step."""

    contacts: int = 0
    rounds: int = 0
    earliest_toi: float = float("inf")
    min_separation: float = float("inf")
    bound_reached: bool = False
    detection_s: float = 0.0
    response_s: float = 0.0
    projections: int = 0


def _tangents(normal: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Two unit tangents ``(k, 3)`` orthogonal to each normal and to each other."""
    helper = np.where(np.abs(normal[:, :1]) < 0.9, [[1.0, 0.0, 0.0]], [[0.0, 1.0, 0.0]])
    t1 = np.cross(normal, helper)
    t1 /= np.linalg.norm(t1, axis=1)[:, None]
    return t1, np.cross(normal, t1)


def _rows(contacts: Contacts) -> tuple[np.ndarray, np.ndarray]:
    """The points ``a - b`` of the contacts' rows ``d . (a - b)``: ``(index (k, 32), weights (k, 32))``."""
    index = np.concatenate([contacts.index_a, contacts.index_b], axis=1)
    return index, np.concatenate([contacts.weights_a, -contacts.weights_b], axis=1)


class ContactHandler:
    """Contact detection and response of a dynamic model, called by the time stepper after each solve.

    Args:
        model: a dynamic :class:`ShellModel`.
        problem: its problem in the solver (``solver.problem``: the projector reuses its
            constraints, the ``"jacobian"`` metric its last Jacobian).
        detector: the scene's colliders and sampling.
        settings: push-out distance and loop bounds.
        options: PETSc options of the projection (under ``prefix``).
        prefix: the projection's PETSc options prefix.

    :meth:`between_bodies` makes the handler of several bodies in one solver: their contacts with
    colliders, themselves and each other, resolved together.
    """

    def __init__(
        self,
        model: ShellModel,
        problem: ShellProblem,
        detector: ContactDetector,
        settings: ContactSettings | None = None,
        options=None,
        prefix: str = "bhem_contact_",
    ):
        settings = self._validated(settings)
        self.check_model(model)
        # the "jacobian" metric: the last Newton iteration's Jacobian, at (nearly) the step's end
        jacobian = problem.jacobian if settings.metric == "jacobian" else None
        projector = ContactProjector(problem, prefix=prefix, options=options)
        surface = ShellContactSurface(model.discretization, model.x.x.array.size)
        self._attach(StackedEntries([surface]), detector, projector, settings, model.comm, jacobian)

    @classmethod
    def between_bodies(
        cls, problems: Sequence[object], detector: BodiesDetector, projector_of: Callable[[int], object],
        comm: MPI.Comm, settings: ContactSettings | None = None,
    ) -> ContactHandler:  # fmt: skip
        """The handler of several bodies (a solver's ``problem.problems``) whose detector has a part
        for each body in contact; ``projector_of(b)`` makes body ``b``'s projector (a shell's
        :class:`ContactProjector`, a solid's
        :class:`~bhem_hpc.contact.solid_projection.SolidContactProjector`)."""
        settings = cls._validated(settings)
        projectors: list[object | None] = [None] * len(problems)
        try:
            for b in detector.in_contact:
                projectors[b] = projector_of(b)
        except Exception:
            for projector in projectors:
                if projector is not None:
                    projector.close()
            raise
        jacobians = [p.jacobian for p in problems] if settings.metric == "jacobian" else None
        handler = cls.__new__(cls)
        handler._attach(detector.entries, detector, StackedProjector(projectors, detector.entries.entry_offsets),
                        settings, comm, jacobians)  # fmt: skip
        return handler

    @staticmethod
    def _validated(settings: ContactSettings | None) -> ContactSettings:
        settings = settings or ContactSettings()
        settings.validate()
        return settings

    @staticmethod
    def check_model(model: ShellModel) -> None:
        """Refuse a shell whose contact rows would push tied control points."""
        if model.ties:
            raise InputError("contact on a model with tied control points (B-spline symmetry planes) is not supported")

    def _attach(self, entries: StackedEntries, detector: ContactDetector | BodiesDetector,
                projector: ContactProjector | StackedProjector, settings: ContactSettings, comm: MPI.Comm,
                jacobian: object) -> None:  # fmt: skip
        self.settings = settings
        self.entries = entries
        self.detector = detector
        self.projector = projector
        self.comm = comm
        # the projector's set_metric argument: a PETSc Jacobian, one per body for several, or None
        self.jacobian = jacobian
        self.history: list[ContactReport] = []

    def _detect(
        self, start: np.ndarray, end: np.ndarray, t: float, dt: float, gap: float, patches: np.ndarray | None = None
    ) -> Contacts:
        comm = self.comm
        try:
            local: Contacts | Exception = self.detector.detect(start, end, t, dt, gap, comm.rank, comm.size, patches)
        except Exception as exc:  # noqa: BLE001 - re-raised on every rank below
            local = exc
        gathered = comm.allgather(local)
        for rank, part in enumerate(gathered):
            if isinstance(part, Exception):  # every rank stops, none waits in a collective
                raise RuntimeError(f"contact detection failed on rank {rank}: {part!r}") from part
        return Contacts.concatenate(gathered)

    def respond(self, x_start: np.ndarray, x_end: np.ndarray, t: float, dt: float
                ) -> tuple[ContactReport, StateCorrection | None]:  # fmt: skip
        """Resolve the contacts of the step from ``x_start`` to the solved ``x_end`` (open layout).

        Returns the report and the correction of velocity and position the contacts need (None
        without contacts); the caller's state applies it (after ``v = (x_end - x_start) / dt``).
        """
        settings = self.settings
        report = ContactReport()
        projections_before = self.projector.projections
        t0 = time.perf_counter()
        start = self.entries.open_to_entries(x_start)
        end = self.entries.open_to_entries(x_end)
        velocity = (end - start) / dt
        gap = settings.push_out
        active = Contacts.empty()
        delta_velocity = np.zeros_like(start)
        delta_position = np.zeros_like(start)
        report.detection_s += time.perf_counter() - t0
        first_end = end
        for round_ in range(settings.max_rounds):
            t1 = time.perf_counter()
            # Round 0 catches everything within the push-out distance; later rounds only what the
            # previous update left closer than half of it (pushed-out points sit at the full distance),
            # on the patches that can hold such a point.
            if round_ == 0:
                found = self._detect(start, end, t, dt, gap)
            else:
                found = self._detect(start, end, t, dt, 0.5 * gap, self._retest(first_end, end, active, 0.5 * gap))
            report.detection_s += time.perf_counter() - t1
            if not len(found):
                break
            report.earliest_toi = min(report.earliest_toi, float(found.toi.min()))
            active = Contacts.concatenate([active, found])
            report.rounds += 1
            t2 = time.perf_counter()
            if round_ == 0:
                self.projector.set_metric(self.jacobian, dt)
            dv, dx = self._respond(active, start, velocity, dt, gap, delta_position)
            velocity = velocity + dv
            delta_velocity += dv
            delta_position += dx  # pushes of all rounds add up
            end = start + dt * velocity + delta_position
            report.response_s += time.perf_counter() - t2
        else:
            final = self._detect(start, end, t, dt, 0.5 * gap, self._retest(first_end, end, active, 0.5 * gap))
            if len(final):
                report.bound_reached = True
                log.warning(
                    "contact: %d contacts still closer than half the push-out distance after %d rounds "
                    "(a smaller time step or a larger effects.contact.push_out resolves them)",
                    len(final),
                    settings.max_rounds,
                )
        report.contacts = len(active)
        report.projections = self.projector.projections - projections_before
        self.history.append(report)
        if not len(active):
            return report, None
        report.min_separation = float((active.separation(end) - active.clearance).min())
        correction = StateCorrection(self.entries.entries_to_open(delta_velocity),
                                     self.entries.entries_to_open(dt * delta_velocity + delta_position))  # fmt: skip
        return report, correction

    def _retest(self, first_end: np.ndarray, end: np.ndarray, found: Contacts, margin: float) -> np.ndarray:
        """Mask ``(n1 * n2,)`` of the patches a later round must test again.

        Round 0 found every point closer than ``gap`` over the motion to ``first_end``; the others
        stayed at least ``gap`` away. A patch point is a convex combination of the patch's Bezier
        control points, so moving the end to ``end`` moves it by at most the largest control-point
        shift, and at every time of the step by no more. A patch that shifted by less than
        ``margin = gap / 2`` cannot bring a point it did not have in contact closer than ``gap / 2``:
        only the other patches, and those touched by a contact found so far, are tested again.
        """
        touched = np.zeros(self.entries.num_entries, dtype=bool)
        touched[found.index_a[found.weights_a != 0]] = True
        touched[found.index_b[found.weights_b != 0]] = True
        # (half the margin: round-off and the projections of collider points are not exact)
        return self.entries.patches_to_retest(end - first_end, touched, 0.5 * margin)

    def _respond(
        self, contacts: Contacts, start: np.ndarray, velocity: np.ndarray, dt: float, gap: float, pushed: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray]:
        """Velocity and position corrections (flat nodal) for the active contacts; ``pushed`` is the
        position correction of earlier rounds."""
        normal = contacts.normal
        wn = np.einsum("kc,kc->k", contacts.obstacle_velocity, normal)
        # Zero restitution: a point may close its distance down to the push-out gap within the step
        # and stops there (its motion past the collision moment is removed). separation(start) is
        # measured to the obstacle's end position: its own motion is added back.
        allowed = np.maximum((contacts.separation(start) - contacts.clearance - gap) / dt + wn, 0.0)
        index, weights = _rows(contacts)
        dv, active = self._inequalities(index, weights, normal, velocity, wn - allowed)
        if len(active) and np.any(contacts.friction[active] > 0):
            dv = self._friction(contacts.take(active), index[active], weights[active], velocity, dv)
        # what the new velocities leave closer than the push-out distance is pushed out to it
        moved = start + dt * (velocity + dv) + pushed
        deficit = gap - (contacts.separation(moved) - contacts.clearance)
        dx, _ = self._inequalities(index, weights, normal, None, deficit)
        return dv, dx

    def _inequalities(
        self,
        index: np.ndarray,
        weights: np.ndarray,
        directions: np.ndarray,
        current: np.ndarray | None,
        lower: np.ndarray,
    ) -> tuple[np.ndarray, np.ndarray]:
        """The smallest correction ``d`` (in the projector's metric) with
        ``rows . (current + d) >= lower`` whose impulses only push.

        The impulses solve a linear complementarity problem on the rows' dual system: a row ends
        above its bound with no impulse, or at its bound pushing. Rows on one patch can outnumber its
        DOFs; the dual system's regularization keeps it positive definite.

        Returns:
            ``(d, rows that push)``.
        """
        base = np.zeros((self.entries.num_entries, 3)) if current is None else current
        value = np.einsum("kj,kjc,kc->k", weights, base[index], directions)
        # rows count as met within round-off of the largest needed change
        tolerance = 1e-9 * max(float(np.abs(lower - value).max(initial=0.0)), 1e-300)
        if not np.any(value < lower - tolerance):
            return np.zeros_like(base), np.zeros(0, np.int64)
        projector = self.projector
        projector.set_rows(index, weights, directions)
        try:
            correction, impulse = projector.solve_pushing(current, lower)
        finally:
            projector.release()
        return correction, np.flatnonzero(impulse > 0.0)

    def _friction(
        self, contacts: Contacts, index: np.ndarray, weights: np.ndarray, velocity: np.ndarray, dv: np.ndarray
    ) -> np.ndarray:
        """Normal rows at their frictionless result plus Coulomb-limited tangential rows, together."""
        normal = contacts.normal
        before = contacts.relative_velocity(velocity)
        after = contacts.relative_velocity(velocity + dv)
        vn_before = np.einsum("kc,kc->k", before, normal)
        vn_after = np.einsum("kc,kc->k", after, normal)
        vt = before - vn_before[:, None] * normal
        speed = np.linalg.norm(vt, axis=1)
        # Coulomb: the tangential speed drops by at most mu times the normal velocity change
        keep = np.maximum(0.0, 1.0 - contacts.friction * (vn_after - vn_before) / np.maximum(speed, 1e-300))
        tangents = _tangents(normal)
        targets = [np.einsum("kc,kc->k", after + contacts.obstacle_velocity, normal)]
        for tangent in tangents:
            targets.append(
                np.einsum("kc,kc->k", contacts.obstacle_velocity, tangent) + keep * np.einsum("kc,kc->k", vt, tangent)
            )
        # the same contact points in three directions: the normal and both tangents
        projector = self.projector
        projector.set_rows(np.tile(index, (3, 1)), np.tile(weights, (3, 1)), np.concatenate([normal, *tangents]))
        try:
            return projector.solve(velocity, np.concatenate(targets))
        finally:
            projector.release()

    def close(self) -> None:
        self.projector.close()

"""Path following for static problems: load control at requested load levels, displacement control
and arc-length continuation, with a PETSc SNES as the Newton engine.

Load control uses the :class:`~bhem_hpc.solver.newton.ShellSolver`'s own SNES (Newton with the
energy line search) at each requested load factor. Displacement control and arc-length continuation
make the load factor ``lambda`` an unknown beside the DOFs: their SNES (type ``python``, own options
prefix, own MUMPS factorization) takes bordered Newton steps (Crisfield): per iteration the tangent
``K`` is factorized once and solved for the residual and for the load vector ``q = -dR/dlambda``,

    K y_R = R,   K y_q = q,   du = -y_R + dlambda y_q,

and ``dlambda`` follows from the linearized constraint: a prescribed displacement component of a
material point (linear: met exactly after each step), or Crisfield's cylindrical arc length
``|u - u_n| = ds sqrt(n)`` on the ``n`` DOFs (``ds`` a root-mean-square change, the same on any mesh;
a quadratic in ``dlambda``: the root that turns least from the step's direction). SNES tests
convergence on ``|R|`` with its tolerances and reports its reasons.

Every converged point records its stability from the inertia of an LDL^T factorization of ``K``
at that point (MUMPS' negative-pivot count, INFOG(12)), which also gives the path's tangent there,
and the events since the last point (:mod:`.path_events`: limit points at the interpolated extremum
of lambda, bifurcations). A displacement or arc-length step that converges on another branch (its
tangent turned back, it lies farther from its predictor than the predictor's length, or its inertia
jumped by more than one eigenvalue) is cut back like a failed one; an arc-length step that leaves
the load-factor range is replaced by the equilibrium at the bound.
"""

from __future__ import annotations

import logging
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field, replace

import numpy as np
from petsc4py import PETSc

from bhem_hpc.model.path import ArcLength, PathSettingError, Probe, ProbeSet, check_levels
from bhem_hpc.solver.linear_strategy import default_options
from bhem_hpc.solver.newton import ShellSolver, jacobian_callback, residual_callback
from bhem_hpc.solver.path_events import PathEvent, PathSample, events_between
from bhem_hpc.solver.petsc import (
    SNES_REASONS,
    PetscOwner,
    SolverError,
    SolverSetupError,
    negative_pivots,
    push_options,
    rejected_options,
    solve_stopped,
)

log = logging.getLogger(__name__)
__all__ = ["ArcLength", "PathError", "PathFollower", "PathPoint", "PathSettingError", "Probe"]


class PathError(SolverError):
    """A path step failed after its bounded cut-backs; ``path`` holds the points converged before."""

    def __init__(self, message: str, path: list[PathPoint]):
        super().__init__(message)
        self.path = path


@dataclass
class PathPoint:
    """One converged equilibrium on the path.

    Attributes:
        step: its index on the path (0: the start).
        load_factor: lambda.
        arc_length: accumulated ``sum |u_k - u_(k-1)| / sqrt(n)`` over the ``n`` DOFs (root-mean-square
            chords between points, so that arc lengths mean the same on any mesh).
        newton_iterations: of the converged solve (cut-back attempts not counted).
        negative_pivots: negative eigenvalues of the tangent (MUMPS INFOG(12) of its LDL^T; -1 when
            the factorization does not report it, e.g. LU).
        event: ``"limit"`` if the load factor passed an extremum since the previous point, else
            ``"bifurcation"`` if the inertia changed otherwise, else ``""``.
        events: those events, located (:mod:`.path_events`: a limit at the interpolated extremum).
        failed_attempts: solves of this step that failed or jumped to another branch before it
            converged (each followed by a cut-back).
        wall_s: wall seconds from the previous point to this one (its attempts and measurement).
        energies: the model's energies (:meth:`ShellModel.energies`).
        probes: per probe name its ``position`` ``(3,)`` and ``displacement`` ``(3,)`` from the
            model's initial surface.
    """

    step: int
    load_factor: float
    arc_length: float
    newton_iterations: int
    negative_pivots: int
    event: str = ""
    events: tuple[PathEvent, ...] = ()
    failed_attempts: int = 0
    wall_s: float = 0.0
    energies: dict[str, float] = field(default_factory=dict)
    probes: dict[str, dict[str, np.ndarray]] = field(default_factory=dict)

    @property
    def stable(self) -> bool | None:
        """Whether the tangent is positive definite (None when the inertia is unknown)."""
        return None if self.negative_pivots < 0 else self.negative_pivots == 0


@dataclass(frozen=True)
class _Candidate:
    """A converged state measured as a path point, before it is accepted (see ``_measure``)."""

    step_length: float  # root-mean-square change from the last point
    negative_pivots: int
    sign: float  # orientation of K^-1 q along the step
    slope_size: float  # |dlambda/ds| = sqrt(n) / |K^-1 q|


class _Jumps:
    """The branch jumps among a step's attempts, for its failure message."""

    def __init__(self) -> None:
        self.count, self.first = 0, ""

    def add(self, why: str) -> bool:
        """Count ``why`` if it names a jump ("" does not); returns whether it did."""
        if why:
            self.count, self.first = self.count + 1, self.first or why
        return bool(why)

    def __str__(self) -> str:
        return f" ({self.count} attempt(s) jumped to another branch: {self.first})" if self.count else ""


class _BorderedStep:
    """The python-SNES context of one constrained solve: a bordered Newton step per iteration.

    ``constraint(x, a, b)`` returns ``dlambda`` such that the new iterate ``x_new = base + a +
    dlambda b`` (``a = x - base - y_R``, ``b = y_q``) meets the path's constraint.
    """

    def __init__(self, follower: PathFollower, base: PETSc.Vec, constraint):
        self.follower = follower
        self.base = base
        self.constraint = constraint
        self.failed = ""

    def step(self, snes: PETSc.SNES, x: PETSc.Vec, f: PETSc.Vec, y: PETSc.Vec) -> None:
        follower = self.follower
        y_r, y_q, a = follower.work
        follower.solve_load_tangent(x, y_q).solve(f, y_r)
        x.copy(a)
        a.axpy(-1.0, self.base)
        a.axpy(-1.0, y_r)
        dlambda = self.constraint(a, y_q)
        if dlambda is None or not np.isfinite(dlambda):
            self.failed = "the constraint has no solution along this Newton step"
            dlambda = 0.0
        # x_new = base + a + dlambda y_q, and SNES applies x_new = x - y
        x.copy(y)
        y.axpy(-1.0, self.base)
        y.axpy(-1.0, a)
        y.axpy(-dlambda, y_q)
        follower.set_load_factor(follower.load_factor + dlambda)


class PathFollower(PetscOwner):
    """Follows the equilibrium path of a static :class:`ShellSolver`'s model from its current state.

    Args:
        solver: the static solver (its model, problem and SNES for load control).
        probes: material points recorded at every path point.
        prefix: options prefix of the constrained SNES (displacement control, arc length);
            its defaults are the solver's (MUMPS LDL^T), and ``snes_linesearch_type basic``.
        options: PETSc options (without prefix) that override those defaults.
        start_load_factor: the load factor of the current state, the path's point 0.
        previous: closed DOFs of the point before the current one (continuing a path): the
            direction in which arc length goes on; None: increasing lambda.
        start_arc_length: the arc length of point 0 (a continued path's).
        first_step: the index of point 0 (a continued path's step).
        on_point: called with every point recorded after point 0 (output, checkpoints).
    """

    def __init__(
        self,
        solver: ShellSolver,
        probes: Sequence[Probe] = (),
        prefix: str = "bhem_path_",
        options: dict[str, object] | None = None,
        start_load_factor: float = 0.0,
        start_arc_length: float = 0.0,
        previous: np.ndarray | None = None,
        first_step: int = 0,
        on_point: Callable[[PathPoint], None] | None = None,
    ):
        self.solver = solver
        self.model = solver.model
        self.problem = solver.problem
        self.prefix = prefix
        self._closed = False
        if self.model.dynamics is not None or len(solver.bodies) > 1:
            raise PathSettingError("path following needs the solver of one static model (dynamics = None), got "
                                   f"{len(solver.bodies)} bodies")  # fmt: skip
        self.probe_set = ProbeSet(self.model, probes)
        self.probes = self.probe_set.probes
        self.on_point = on_point
        self.x = solver.x
        self.problem.state_to_vector(self.x)
        self.jacobian = self.problem.jacobian
        self.q = self.x.duplicate()
        self.tangent = self.x.duplicate()  # K^-1 q at the last point, signed along the path
        self._trial_tangent = self.x.duplicate()  # the same at a candidate point
        self.work = [self.x.duplicate() for _ in range(3)]
        self._residual_scratch = self.x.duplicate()
        self._last = self.x.copy()  # the DOFs of the last recorded point
        if previous is not None:
            self._last.array[:] = previous
        self._snes = self._create_snes(options or {})
        self.load_factor = float(start_load_factor)
        self.set_load_factor(self.load_factor)
        self._sign = 1.0  # the sign of dlambda/ds at the last point
        self._sample = PathSample(0.0, 0.0, 0.0, -1)  # the last point, for the events after it
        self.path: list[PathPoint] = []
        self._first_step = first_step
        self._start_arc_length = float(start_arc_length)
        self.arc_step = float("nan")  # the adapted arc length of the next step (arc-length continuation)
        self._rms = float(np.sqrt(self.x.getSize()))  # arc lengths are root-mean-square DOF changes
        self._continuing = previous is not None  # the path's direction is the step that led to its start
        self._failed_attempts, self._since = 0, time.perf_counter()
        self._record(0, continuing=self._continuing)

    # -- setup ------------------------------------------------------------------------------------
    def _create_snes(self, options: dict[str, object]) -> PETSc.SNES:
        opts = PETSc.Options()
        self._overrides = push_options(self.prefix, {}, options)
        defaults = default_options(self.model) | {"snes_type": "python", "snes_linesearch_type": "basic"}
        pushed = push_options(self.prefix, defaults, {})
        try:
            snes = PETSc.SNES().create(self.model.comm)
            snes.setOptionsPrefix(self.prefix)
            snes.setType("python")
            snes.setFunction(residual_callback, self.solver.f, kargs={"solver": self.solver})
            snes.setJacobian(jacobian_callback, self.jacobian, self.jacobian, kargs={"solver": self.solver})
            try:
                snes.setFromOptions()
            except PETSc.Error as exc:
                snes.destroy()
                raise rejected_options(f"SNES solver '{self.prefix}'", exc) from None
            if snes.getType() != "python":
                snes.destroy()
                raise SolverSetupError(f"SNES solver '{self.prefix}': snes_type must stay 'python' (bordered steps)")
        finally:
            for name in pushed:
                opts.delValue(name)
        return snes

    def set_load_factor(self, value: float) -> None:
        self.load_factor = float(value)
        self.model.load_factor.value = self.load_factor

    def load_vector(self, x: PETSc.Vec, q: PETSc.Vec) -> None:
        """``q = -dR/dlambda`` at ``x``: the residual is affine in lambda, so ``R(x, 0) - R(x, 1)``
        (zero on prescribed rows, whose values do not move with lambda)."""
        current = self.model.load_factor.value
        self.problem.update_state(x)
        self.model.load_factor.value = 0.0
        self.problem.assemble_residual(x, q)
        self.model.load_factor.value = 1.0
        self.problem.assemble_residual(x, self._residual_scratch)
        q.axpy(-1.0, self._residual_scratch)
        self.model.load_factor.value = current

    def solve_load_tangent(self, x: PETSc.Vec, out: PETSc.Vec) -> PETSc.KSP:
        """Factorize the tangent ``K`` at ``x``, solve ``K out = q`` (the load vector) and return the
        KSP holding the factorization, for more solves with it."""
        self._snes.computeJacobian(x, self.jacobian)
        ksp = self._snes.getKSP()
        ksp.setOperators(self.jacobian)
        self.load_vector(x, self.q)
        ksp.solve(self.q, out)
        return ksp

    # -- measurements -----------------------------------------------------------------------------
    def _functional(self, probe: Probe, component: int) -> PETSc.Vec:
        """Closed-DOF vector ``c`` with ``c . x`` = component of the probe's position."""
        blocks, values = self.model.discretization.point_basis(probe.xi1, probe.xi2)
        open_vector = self.problem.f_open.duplicate()
        with open_vector.localForm() as local:
            local.set(0.0)
            local.array[3 * blocks + component] += values
        open_vector.ghostUpdate(addv=PETSc.InsertMode.ADD, mode=PETSc.ScatterMode.REVERSE)
        closed = self.x.duplicate()
        if self.problem.prolongation is not None:
            self.problem.prolongation.multTranspose(open_vector, closed)
        else:
            open_vector.copy(closed)
        open_vector.destroy()
        return closed

    def _measure(self, continuing: bool = False) -> _Candidate:
        """The current state as a candidate point: the step from the last point, the tangent and
        inertia from one factorization of ``K`` here (the tangent into :attr:`_trial_tangent`,
        oriented along the step; none: increasing lambda)."""
        increment = self.x.copy()
        increment.axpy(-1.0, self._last)
        step_length = increment.norm() / self._rms if self.path else 0.0
        ksp = self.solve_load_tangent(self.x, self._trial_tangent)
        oriented = self.path or continuing
        sign = 1.0 if not oriented or self._trial_tangent.dot(increment) >= 0 else -1.0
        increment.destroy()
        self._trial_tangent.scale(sign)
        return _Candidate(step_length, negative_pivots(ksp), sign, self._rms / max(self._trial_tangent.norm(), 1e-300))

    def _branch_jump(self, candidate: _Candidate, predictor: PETSc.Vec, minimal_step: bool,
                     origin: PETSc.Vec | None = None) -> str:  # fmt: skip
        """Why a converged step left the branch it started on ("" if it did not): its tangent turned
        back against the last point's, it lies farther from its predictor ``x_pred - origin`` (the
        step's start, by default the last point) than the predictor's own length, or (above the
        smallest step) its inertia changed by more than one eigenvalue."""
        if self.path and self._trial_tangent.dot(self.tangent) < 0:
            return "the path's tangent reversed"
        length = predictor.norm()
        away = self.x.copy()
        away.axpy(-1.0, self._last if origin is None else origin)
        away.axpy(-1.0, predictor)
        distance = away.norm()
        away.destroy()
        if length > 0 and distance > length:
            return f"it lies {distance / length:.2f} predictor lengths from its predictor"
        last, now = self.path[-1].negative_pivots if self.path else -1, candidate.negative_pivots
        if not minimal_step and last >= 0 and now >= 0 and abs(now - last) > 1:
            return f"its inertia jumped from {last} to {now} negative pivots"
        return ""

    def _record(self, iterations: int, continuing: bool = False, candidate: _Candidate | None = None) -> PathPoint:
        """Record the current state as a path point (measured unless ``candidate`` is its
        measurement): its tangent becomes the path's, its events since the last point (limit points
        at the interpolated extremum of lambda, bifurcations), energies and probes."""
        candidate = candidate or self._measure(continuing)
        self.tangent, self._trial_tangent = self._trial_tangent, self.tangent
        self.x.copy(self._last)
        self.problem.update_state(self.x)
        arc_length = (self.path[-1].arc_length if self.path else self._start_arc_length) + candidate.step_length
        sample = PathSample(arc_length, self.load_factor, candidate.sign * candidate.slope_size,
                            candidate.negative_pivots)  # fmt: skip
        events = events_between(self._sample, sample) if self.path else ()
        self._sign, self._sample = candidate.sign, sample
        point = PathPoint(
            step=self._first_step + len(self.path),
            load_factor=self.load_factor,
            arc_length=arc_length,
            newton_iterations=iterations,
            negative_pivots=candidate.negative_pivots,
            event=next((e.kind for e in events if e.kind == "limit"), events[0].kind if events else ""),
            events=events,
            failed_attempts=self._failed_attempts,
            wall_s=time.perf_counter() - self._since,
            energies=self.model.energies(),
            probes=self.probe_set.record(),
        )
        for event in events:
            log.info("%s: %s point at load factor %.6g (between path points %d and %d)", self.prefix, event.kind,
                     event.load_factor, point.step - 1, point.step)  # fmt: skip
        self.path.append(point)
        self._failed_attempts = 0
        if self.on_point is not None and len(self.path) > 1:
            self.on_point(point)
        self._since = time.perf_counter()  # the next step's clock starts after this point's output
        return point

    # -- load control -----------------------------------------------------------------------------
    def load_control(self, levels: Sequence[float], *, max_cuts: int = 8) -> list[PathPoint]:
        """Equilibria at exactly the load factors ``levels``, in order, each from the previous one.

        A level whose solve fails is approached through intermediate load factors (halving the
        distance, at most ``max_cuts`` times in a row); only the requested levels are recorded.

        Raises:
            PathError: a level was not reached; the path so far is kept.
        """
        targets = check_levels("load levels", levels)
        accepted, before = self.x.copy(), self.x.copy()  # the last two equilibria, for the secant
        factor_before = None
        try:
            for level in targets:
                reached, cuts, iterations = self.load_factor, 0, 0
                while reached != level:
                    trial = level if cuts == 0 else reached + (level - reached) / 2**cuts
                    if factor_before is not None and factor_before != reached:  # secant predictor
                        self.x.axpy((trial - reached) / (reached - factor_before), accepted - before)
                    if self.solver.solve_at(trial):
                        accepted.copy(before)
                        factor_before, reached, cuts = reached, trial, max(cuts - 1, 0)
                        iterations = self.solver.snes.getIterationNumber()
                        self.x.copy(accepted)
                        self.set_load_factor(trial)
                        continue
                    accepted.copy(self.x)
                    self._failed_attempts += 1
                    cuts += 1
                    if cuts > max_cuts:
                        self.set_load_factor(reached)
                        self._fail(f"load factor {level:.6g} not reached (from {reached:.6g})", self.solver.snes)
                self._record(iterations)
        finally:
            accepted.destroy()
            before.destroy()
        return self.path

    # -- displacement control ---------------------------------------------------------------------
    def displacement_control(
        self, probe: str, component: int | str, values: Sequence[float], *, max_cuts: int = 8
    ) -> list[PathPoint]:
        """Equilibria where the probe's displacement component (``"x"``, ``"y"``, ``"z"`` or 0, 1, 2; from the path's
        start) takes ``values``, in order; the load factor is the unknown.

        Raises:
            PathSettingError: an unknown probe or component.
            PathError: a value was not reached after ``max_cuts`` halvings; the path so far is kept.
        """
        names = [p.name for p in self.probes]
        if probe not in names:
            raise PathSettingError(f"displacement control names probe {probe!r}; the probes are {names}")
        component = {"x": 0, "y": 1, "z": 2}.get(component, component) if isinstance(component, str) else component
        if isinstance(component, bool) or component not in (0, 1, 2):
            raise PathSettingError(f"displacement control component = {component!r}; expected 'x', 'y', 'z' or 0, 1, 2")
        targets = check_levels("displacement values", values)
        self._check_fixed_supports()
        index = names.index(probe)
        c = self._functional(self.probes[index], component)
        offset = self.probe_set.start[index][component]
        try:
            for value in targets:
                self._advance_displacement(c, offset, value, max_cuts)
        finally:
            c.destroy()
        return self.path

    def _advance_displacement(self, c: PETSc.Vec, offset: float, value: float, max_cuts: int) -> None:
        """Reach the displacement ``value`` from the last point, halving the remaining change when a
        solve fails or lands on another branch; records the point."""
        reached = c.dot(self.x) - offset
        cuts, iterations, jumps = 0, 0, _Jumps()
        base, predictor = self.x.copy(), self.x.duplicate()
        previous_factor = self.load_factor
        try:
            while True:
                trial = value if cuts == 0 else reached + (value - reached) / 2**cuts
                base_value = c.dot(base)

                def constraint(a: PETSc.Vec, b: PETSc.Vec, trial=trial, base_value=base_value) -> float | None:
                    slope = c.dot(b)
                    if slope == 0.0:
                        return None
                    return (trial + offset - base_value - c.dot(a)) / slope

                self._predict_displacement(c, base, trial + offset - base_value)
                self.x.copy(predictor)
                predictor.axpy(-1.0, base)
                candidate = None
                if self._constrained_solve(base, constraint):
                    candidate = self._measure()
                    if jumps.add(self._branch_jump(candidate, predictor, cuts == max_cuts, origin=base)):
                        log.info("%s: the displacement step to %.6g jumped to another branch (%s): cut back",
                                 self.prefix, trial, jumps.first)  # fmt: skip
                        candidate = None
                if candidate is not None:
                    iterations = self._snes.getIterationNumber()
                    reached = trial
                    self.x.copy(base)
                    previous_factor = self.load_factor
                    if trial == value:
                        break
                    cuts = max(cuts - 1, 0)
                    continue
                base.copy(self.x)
                self.set_load_factor(previous_factor)
                self._failed_attempts += 1
                cuts += 1
                if cuts > max_cuts:
                    advice = "; arc length (method = 'arc_length') follows a snap-back" if jumps.count else ""
                    self._fail(f"displacement {value:.6g} not reached (from {reached:.6g}){jumps}{advice}", self._snes)
        finally:
            base.destroy()
            predictor.destroy()
        self._record(iterations, candidate=candidate)

    def _check_fixed_supports(self) -> None:
        model = self.model
        if self.solver.prescribed is not None or np.any(model.constrained_target != model.constrained_initial):
            raise PathSettingError(
                "displacement control and arc length keep prescribed values fixed: the model prescribes "
                "values that move with the load factor (make them the initial state, or use load control)"
            )

    def _predict_displacement(self, c: PETSc.Vec, base: PETSc.Vec, change: float) -> None:
        """Start from ``base`` moved along the last point's tangent by the load-factor increment that
        changes ``c . x`` by ``change`` (the solve then starts off equilibrium, as SNES needs to
        iterate; a tangent that does not move ``c . x`` leaves the start at ``base``)."""
        base.copy(self.x)
        slope = self._sign * c.dot(self.tangent)  # c . K^-1 q
        if slope != 0.0:
            increment = change / slope
            self.x.axpy(self._sign * increment, self.tangent)
            self.set_load_factor(self.load_factor + increment)

    def _constrained_solve(self, base: PETSc.Vec, constraint) -> bool:
        """One SNES solve of the bordered system from ``self.x`` (``base``: the step's start)."""
        context = _BorderedStep(self, base, constraint)
        self._snes.setPythonContext(context)
        try:
            self._snes.solve(None, self.x)
        except PETSc.Error as exc:
            raise solve_stopped(self.prefix, exc) from None
        converged = self._snes.getConvergedReason() > 0 and np.isfinite(self._snes.getFunctionNorm())
        if context.failed:
            log.info("%s: %s", self.prefix, context.failed)
        return converged and not context.failed

    def _fail(self, what: str, snes: PETSc.SNES) -> None:
        reason = snes.getConvergedReason()
        step = self._first_step + len(self.path)
        raise PathError(
            f"path step {step} at load factor {self.load_factor:.6g} failed: {what} after its "
            f"cut-backs; SNES '{snes.getOptionsPrefix()}': {SNES_REASONS.get(reason, reason)}, "
            f"|F| = {snes.getFunctionNorm():.3e}",
            self.path,
        )

    # -- arc length -------------------------------------------------------------------------------
    def arc_length(self, settings: ArcLength) -> list[PathPoint]:
        """Crisfield's cylindrical arc-length continuation from the current point, until lambda leaves
        ``settings.load_factor_range`` or ``settings.max_steps`` points are added.

        Raises:
            PathError: a step failed after ``settings.max_cuts`` halvings of ``ds``; the path so far
                is kept.
        """
        settings.validate()
        self._check_fixed_supports()
        low, high = settings.load_factor_range
        # from the start of a path (not a continued one): the given direction
        if len(self.path) == 1 and not self._continuing and self._sign != settings.direction:
            self.tangent.scale(-1.0)
            self._sign = float(settings.direction)
            self._sample = replace(self._sample, slope=-self._sample.slope)
        self.arc_step = settings.initial_step
        base = self.x.copy()
        predictor = self.x.duplicate()
        try:
            for _ in range(settings.max_steps):
                self._arc_length_step(base, predictor, settings)
                if not low < self.load_factor < high:
                    break
        finally:
            base.destroy()
            predictor.destroy()
        return self.path

    def _arc_length_step(self, base: PETSc.Vec, predictor: PETSc.Vec, settings: ArcLength) -> None:
        """One arc-length step of :attr:`arc_step` from ``base`` (the last point) along
        :attr:`tangent`, halving it when it fails or jumps to another branch; adapts
        :attr:`arc_step` to the Newton iterations taken and records the point (at the range's bound
        if the step crossed it)."""
        start_factor = self.load_factor
        step_length = self.arc_step
        jumps = _Jumps()
        for cuts in range(settings.max_cuts + 1):
            # |du| = ds sqrt(n): ds is a root-mean-square change, the same on any mesh; dlambda = sign * scale
            scale = step_length * self._rms / max(self.tangent.norm(), 1e-300)
            self.tangent.copy(predictor)
            predictor.scale(scale)
            base.copy(self.x)
            self.x.axpy(1.0, predictor)
            self.set_load_factor(start_factor + self._sign * scale)
            smallest = cuts == settings.max_cuts or step_length / 2 < settings.min_step
            if self._constrained_solve(base, self._arc_constraint(step_length * self._rms, predictor)):
                iterations = self._snes.getIterationNumber()
                candidate = self._measure()
                if not jumps.add(self._branch_jump(candidate, predictor, smallest)):
                    growth = np.clip(np.sqrt(settings.target_iterations / max(iterations, 1)), 0.5, 2.0)
                    self.arc_step = float(np.clip(step_length * growth, settings.min_step, settings.max_step))
                    bounded = self._end_at_bound(base, start_factor, settings.load_factor_range)
                    self.x.copy(base)
                    self._record(self._snes.getIterationNumber() if bounded else iterations,
                                 candidate=None if bounded else candidate)  # fmt: skip
                    return
                log.info("%s: an arc-length step of %.3g jumped to another branch (%s): cut back", self.prefix,
                         step_length, jumps.first)  # fmt: skip
            base.copy(self.x)
            self.set_load_factor(start_factor)
            self._failed_attempts += 1
            if smallest:
                break
            step_length /= 2
        self._fail(f"arc-length step of {step_length:.3g} not converged{jumps}", self._snes)

    def _end_at_bound(self, base: PETSc.Vec, start_factor: float, load_factor_range: tuple[float, float]) -> bool:
        """If the converged step left ``load_factor_range``, replace it by the equilibrium at the
        bound it crossed (from ``base``, the last point, predicted by interpolating the step);
        returns whether it did. A bound solve that fails keeps the step beyond it, with a warning."""
        factor = self.load_factor
        low, high = load_factor_range
        if low < factor < high:
            return False
        bound = high if factor >= high else low
        overshoot, beyond = self.x.copy(), factor
        fraction = (bound - start_factor) / (factor - start_factor)
        self.x.scale(fraction)  # base + fraction (x - base)
        self.x.axpy(1.0 - fraction, base)
        self.set_load_factor(bound)
        if self._constrained_solve(base, lambda a, b: bound - self.load_factor):
            overshoot.destroy()
            return True
        log.warning("%s: the equilibrium at the load-factor bound %.6g did not converge: the path ends at %.6g",
                    self.prefix, bound, beyond)  # fmt: skip
        overshoot.copy(self.x)
        overshoot.destroy()
        self.set_load_factor(beyond)
        return False

    def _arc_constraint(self, step_length: float, predictor: PETSc.Vec):
        """``dlambda`` with ``|a + dlambda b| = ds``: of the two roots, the one whose increment is
        closer in direction to the predictor; without a real root, the closest approach."""

        def constraint(a: PETSc.Vec, b: PETSc.Vec) -> float | None:
            bb, ab, aa = b.dot(b), a.dot(b), a.dot(a)
            if bb == 0.0:
                return None
            discriminant = ab * ab - bb * (aa - step_length**2)
            if discriminant < 0:
                return -ab / bb
            roots = [(-ab + sign * np.sqrt(discriminant)) / bb for sign in (1.0, -1.0)]
            a_dot_p, b_dot_p = a.dot(predictor), b.dot(predictor)
            return max(roots, key=lambda r: a_dot_p + r * b_dot_p)

        return constraint

    # -- lifetime ---------------------------------------------------------------------------------
    def close(self) -> None:
        """Destroy the PETSc objects this follower owns and remove its options (idempotent)."""
        if self._closed:
            return
        self._closed = True
        for vec in [self.q, self.tangent, self._trial_tangent, *self.work, self._residual_scratch, self._last]:
            vec.destroy()
        self._snes.destroy()
        opts = PETSc.Options()
        for name in self._overrides:
            opts.delValue(name)


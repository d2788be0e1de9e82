"""The discrete shell model: state, rest state, and its energy and load terms as compiled dolfinx forms.

The model is a list of :class:`Term` objects (membrane, bending, gravity, inertia, damping, loads),
each one energy or work form from :mod:`bhem_hpc.forms`; one composition turns them into the total
potential, the residual and the exact or pseudo Jacobian. Only what a scene asks for is built: an
absent load adds no term and compiles nothing. The PETSc side lives in :mod:`bhem_hpc.solver`.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from typing import Literal

import dolfinx.fem as fem
import numpy as np
import ufl
from mpi4py import MPI

from bhem_hpc import forms
from bhem_hpc.discretization import ConstrainedDofs, Discretization, create_discretization
from bhem_hpc.geometry.bspline import DEFAULT_QUADRATURE
from bhem_hpc.geometry.surface import HermiteSurface
from bhem_hpc.model.bcs import NodalConstraint, NodalTie, target_surface
from bhem_hpc.model.hessian import COMPOSED_HESSIANS, HESSIAN_KINDS, HessianKind
from bhem_hpc.model.jit import compilation_report, default_jit_params
from bhem_hpc.model.loads import (  # noqa: F401 - re-exported: the model API
    AreaLoad,
    Dynamics,
    EdgeMoment,
    LineLoad,
    Loads,
    ModelError,
    PointConstraint,
    PointLoad,
)
from bhem_hpc.model.material import Material
from bhem_hpc.model.quadrature import Quadrature, QuadratureError, check_quadrature, edge_measure, shell_quadrature
from bhem_hpc.model.trimmed import Trim, check_model, outside_constraints, restrict_term, weight_function

ScalarType = np.float64  # the dolfinx build is real, double precision


@dataclass(frozen=True)
class Term:
    """One term of the model: an energy, a load's virtual work, or a reported quantity.

    Attributes:
        name: the term's name (the key of :meth:`ShellModel.energies` when reported).
        form: a potential (rank-0 form in the position ``x``) or, for ``role="work"``, a virtual
            work (rank-1 form in the test function).
        role: ``"potential"`` (enters the total potential), ``"work"`` (enters the residual) or
            ``"report"`` (only reported, e.g. the kinetic energy).
        load_scaled: multiplied by the load factor (external loads).
        hessians: by Hessian kind (``"pseudo"``, ``"projected"``), a ``(test, trial) -> form`` that
            replaces the term's exact Hessian under that kind; a kind not listed keeps the exact one
            (right for terms whose Hessian is positive semi-definite already: inertia, dead loads).
        conservative: a work that has a potential, ``-work[x]`` (dead loads; a follower pressure
            has none, and makes the problem non-symmetric).
        reported: listed by :meth:`ShellModel.energies`.
    """

    name: str
    form: ufl.Form
    role: Literal["potential", "work", "report"] = "potential"
    load_scaled: bool = False
    hessians: Mapping[str, Callable[[ufl.Argument, ufl.Argument], ufl.Form]] = field(default_factory=dict)
    conservative: bool = True
    reported: bool = False

    def scaled(self, load_factor: fem.Constant) -> ufl.Form:
        """The term's form with the load factor applied where it scales."""
        return load_factor * self.form if self.load_scaled else self.form


class ShellModel:
    """A Kirchhoff-Love shell discretized by bicubic Hermite patches.

    Args:
        rest: rest (reference) surface; also the initial state unless ``initial`` is given.
        material: material constants.
        loads: external loads (only those given are built).
        constraints: nodal boundary conditions (:class:`~bhem_hpc.model.bcs.NodalConstraint`) and, on
            B-spline surfaces, ties of control points (:class:`~bhem_hpc.model.bcs.NodalTie`).
        hessian: the Jacobian Newton iterates with (the residual and so the solution do not depend
            on it): ``"exact"`` (UFL derivative of the residual; the default for statics, where its
            inertia tells stability), ``"pseudo"`` (the BHEM paper's: the second derivative of the
            curvature strain is dropped) or ``"projected"`` (positive semi-definite: the pseudo
            Hessian of bending and the membrane's geometric stiffness from the tensile part of its
            stress only, so that every Newton step of a time step goes downhill; the default for
            dynamics). None: the default.
        quadrature_points: Gauss points per direction and patch, or ``"reduced"`` (quadratic
            B-splines: the B-spline paper's reduced rule for membrane and bending, see
            :mod:`bhem_hpc.model.quadrature`; mass and loads keep 3 x 3 Gauss); default: the
            surface's :data:`DEFAULT_QUADRATURE` (4 x 4 for bicubic Hermite and cubic B-splines, the
            BHEM paper's rule; 3 x 3 for quadratic B-splines); or a :class:`~bhem_hpc.geometry.trim.Trim`:
            its cut-cell rule on its Gauss points, and only the part of the surface it keeps simulated.
        comm: MPI communicator.
        initial: initial state (default: the rest surface).
        point_constraints: material points held at (moving) targets by the augmented Lagrangian
            method in the solver.
        dynamics: time stepping; adds inertia (and damping) potentials, the ``x_predicted``,
            ``x_previous`` and ``velocity`` Functions and a ``kinetic`` energy. ``None``: statics.
    """

    def __init__(
        self,
        rest: HermiteSurface,
        material: Material,
        loads: Loads | None = None,
        constraints: Sequence[NodalConstraint] = (),
        hessian: HessianKind | None = None,
        quadrature_points: Quadrature | Trim | None = None,
        comm: MPI.Comm = MPI.COMM_WORLD,
        initial: HermiteSurface | None = None,
        dynamics: Dynamics | None = None,
        point_constraints: Sequence[PointConstraint] = (),
    ):
        loads = loads or Loads()
        trim = quadrature_points if isinstance(quadrature_points, Trim) else None
        if trim is not None:
            quadrature_points = trim.points
        if hessian is None:
            hessian = "exact" if dynamics is None else "adaptive"
        if quadrature_points is None:
            quadrature_points = DEFAULT_QUADRATURE[rest.discretization]
        _validate(rest, initial or rest, loads, constraints, hessian, quadrature_points, dynamics,
                  point_constraints, material)  # fmt: skip
        if trim is not None:
            check_model(trim, rest.grid, loads, point_constraints)
        initial = initial or rest
        self.comm = comm
        self.material = material
        self.loads = loads
        self.hessian = hessian
        self.quadrature_points = quadrature_points
        self.rest_surface = rest
        self.initial_surface = initial
        self.constraints = tuple(c for c in constraints if not isinstance(c, NodalTie))
        self.ties = tuple(c for c in constraints if isinstance(c, NodalTie))
        self.dynamics = dynamics
        self.discretization: Discretization = create_discretization(rest, comm)
        if self.ties:
            self.discretization.set_ties(self.ties, rest)
        self.trim = trim  # entries that move no kept point are held
        if trim is not None:
            self.constraints += tuple(outside_constraints(self.discretization.patches.patch_entries(), trim,
                                                          rest.node_shape, rest.kind_count))  # fmt: skip
        space = self.discretization.function_space
        self.x = fem.Function(space, name="position")
        self.x_rest = fem.Function(space, name="rest_position")
        #: the Functions that hold positions (or velocities) in the discretization's open layout
        self.position_functions = [self.x, self.x_rest]
        self.x.x.array[:] = self.discretization.surface_to_open(initial)
        self.x_rest.x.array[:] = self.discretization.surface_to_open(rest)
        self.young = self._constant(material.young)
        self.poisson = self._constant(material.poisson)
        self.thickness = self._constant(material.thickness)
        self.density = self._constant(material.density)
        self.load_factor = self._constant(1.0)
        self.quadrature = shell_quadrature(self.discretization.grid_mesh, quadrature_points)
        self.trim_weight = None if trim is None else weight_function(self.discretization.grid_mesh, trim)
        self._term_residual_forms: dict[str, fem.Form] | None = None
        self.dx = self.quadrature.mass
        self._compose_forms()
        self._build_point_data(loads, point_constraints)

    def _constant(self, value) -> fem.Constant:
        return fem.Constant(self.discretization.mesh, ScalarType(value))

    def _terms(self, test: ufl.Argument) -> list[Term]:
        """The model's terms, in the order their forms are summed: only what the model asks for."""
        x, x_rest, dx = self.x, self.x_rest, self.dx
        terms = self._elastic_terms(x)
        if self.loads.gravity is not None:
            self.gravity = self._constant(np.asarray(self.loads.gravity, dtype=float))
            gravity = forms.gravity_potential(x, x_rest, self.density, self.thickness, self.gravity, dx)
            terms.append(Term("gravity", gravity, load_scaled=True, reported=True))
        terms += self._area_load_terms()
        if self.dynamics is not None:
            terms += self._inertia_terms()
        return terms + self._work_terms(test)

    def _elastic_terms(self, position: fem.Function) -> list[Term]:
        """Membrane and bending energies of the shell at ``position`` (the state, or the previous
        state for stiffness damping), of the material's models, each with its replacement Hessians."""
        bending = [] if self.material.bending == "none" else [self._bending_term(position)]
        return [self._membrane_term(position), *bending]

    def _membrane_term(self, position: fem.Function) -> Term:
        x_rest, dx, material = self.x_rest, self.quadrature.membrane, self.material
        if material.membrane == "fbw":
            stretch = self._constant(material.stretch_stiffness)
            shear = self._constant(material.stretch_stiffness * material.shear_ratio)

            def fbw_projected(v, u):
                return forms.baraff_witkin_projected_hessian(position, x_rest, stretch, shear, dx, v, u)

            energy = forms.baraff_witkin_energy(position, x_rest, stretch, shear, dx)
            return Term("membrane", energy, hessians={"projected": fbw_projected, "out_of_plane": fbw_projected},
                        reported=True)  # fmt: skip
        section = (self.thickness, self.young, self.poisson)

        def projected(v, u):
            return forms.membrane_projected_hessian(position, x_rest, *section, dx, v, u)

        def out_of_plane(v, u):
            return forms.membrane_projected_hessian(position, x_rest, *section, dx, v, u, True)

        return Term("membrane", forms.membrane_energy(position, x_rest, *section, dx),
                    hessians={"projected": projected, "out_of_plane": out_of_plane}, reported=True)  # fmt: skip

    def _bending_term(self, position: fem.Function) -> Term:
        x_rest, dx = self.x_rest, self.quadrature.bending
        if self.material.bending == "quadratic":  # quadratic: its exact Hessian is constant and positive
            stiffness = self._constant(self.material.bending_stiffness)
            return Term("bending", forms.quadratic_bending_energy(position, x_rest, stiffness, dx), reported=True)
        section = (self.thickness, self.young, self.poisson)

        def gauss_newton(v, u):
            return forms.bending_pseudo_hessian(position, x_rest, *section, dx, v, u)

        energy = forms.bending_energy(position, x_rest, *section, dx)
        kinds = ("pseudo", "projected", "out_of_plane")
        return Term("bending", energy, hessians=dict.fromkeys(kinds, gauss_newton), reported=True)

    def _damping_stiffness(self, position: fem.Function, test, trial) -> ufl.Form:
        """The positive semi-definite (projected) elastic Hessian ``K+`` at ``position`` as a bilinear
        form: a damping matrix must not be indefinite, or compressed regions would gain energy."""
        elastic = self._elastic_terms(position)
        return _sum_forms([
            t.hessians["projected"](test, trial) if "projected" in t.hessians
            else ufl.derivative(ufl.derivative(t.form, position, test), position, trial)
            for t in elastic
        ])  # fmt: skip

    def _area_load_terms(self) -> list[Term]:
        """Dead area loads: potentials ``-q . x`` with ``q = force * profile(xi)``."""
        xi = ufl.SpatialCoordinate(self.discretization.mesh)
        self.area_load_forces = []
        terms = []
        for i, load in enumerate(self.loads.area_loads):
            force = self._constant(np.asarray(load.force, dtype=float))
            self.area_load_forces.append(force)
            density = force if load.profile is None else load.profile(xi) * force
            potential = forms.area_load_potential(self.x, self.x_rest, density, self.dx)
            terms.append(Term(f"area_load_{i}", potential, load_scaled=True, reported=True))
        return terms

    def _inertia_terms(self) -> list[Term]:
        """Implicit Euler's inertia and Rayleigh damping potentials, and the kinetic energy report."""
        dynamics, space, x, x_rest, dx = self.dynamics, self.discretization.function_space, self.x, self.x_rest, self.dx
        self.time_step = self._constant(dynamics.time_step)
        self.x_predicted = fem.Function(space, name="predicted_position")
        self.x_previous = fem.Function(space, name="previous_position")
        self.velocity = fem.Function(space, name="velocity")
        self.position_functions += [self.x_predicted, self.x_previous, self.velocity]
        self.x_predicted.x.array[:] = self.x.x.array
        self.x_previous.x.array[:] = self.x.x.array
        rho_h = (self.density, self.thickness)
        terms = [Term("inertia", forms.inertia_potential(x, self.x_predicted, x_rest, *rho_h, self.time_step, dx))]
        if dynamics.mass_damping > 0:
            self.mass_damping = self._constant(dynamics.mass_damping)
            damping = forms.mass_damping_potential(
                x, self.x_previous, x_rest, *rho_h, self.mass_damping, self.time_step, dx
            )
            terms.append(Term("mass_damping", damping))
        if dynamics.stiffness_damping > 0:
            self.stiffness_damping = self._constant(dynamics.stiffness_damping)
            test, trial = ufl.TestFunction(space), ufl.TrialFunction(space)
            damping = forms.stiffness_damping_potential(
                self._damping_stiffness(self.x_previous, test, trial), x, self.x_previous, self.stiffness_damping,
                self.time_step,
            )
            terms.append(Term("stiffness_damping", damping))
        kinetic = forms.kinetic_energy(self.velocity, x_rest, *rho_h, dx)
        return [*terms, Term("kinetic", kinetic, role="report", reported=True)]

    def _work_terms(self, test: ufl.Argument) -> list[Term]:
        """External virtual work: a follower pressure (no potential), then dead line loads."""
        terms = []
        if self.loads.pressure is not None:
            self.pressure = self._constant(self.loads.pressure)
            pressure = forms.pressure_work(self.x, self.pressure, test, self.dx)
            terms.append(Term("pressure", pressure, role="work", load_scaled=True, conservative=False))
        if self.loads.line_loads:
            ds = self._edge_measure([load.edge for load in self.loads.line_loads])
            self.tractions = []
            for i, load in enumerate(self.loads.line_loads):
                traction = self._constant(np.asarray(load.traction, dtype=float))
                self.tractions.append(traction)
                work = forms.line_load_work(self.x_rest, traction, test, ds(i + 1))
                terms.append(Term(f"line_load_{i}", work, role="work", load_scaled=True))
        if self.loads.edge_moments:
            ds = self._edge_measure([load.edge for load in self.loads.edge_moments])
            self.edge_moments = []
            for i, load in enumerate(self.loads.edge_moments):
                moment = self._constant(float(load.moment))
                self.edge_moments.append(moment)
                work = forms.edge_moment_work(self.x, self.x_rest, moment, test, ds(i + 1))
                # the axis follows the edge: no potential in general, a non-symmetric tangent
                terms.append(Term(f"edge_moment_{i}", work, role="work", load_scaled=True, conservative=False))
        return terms

    def _edge_measure(self, edges: Sequence[str]) -> ufl.Measure:
        return edge_measure(self.discretization.mesh, self.rest_surface.grid, edges)

    def _compose_forms(self) -> None:
        """One composition of the terms: total potential, residual, Jacobian of the model's Hessian
        kind, reports."""
        x, lf = self.x, self.load_factor
        space = self.discretization.function_space
        test, trial = ufl.TestFunction(space), ufl.TrialFunction(space)
        self.terms = self._terms(test)
        if self.trim_weight is not None:  # every cell integrand weighted by the cut-cell rule
            self.terms = [restrict_term(term, self.trim_weight) for term in self.terms]
        potentials = [t for t in self.terms if t.role == "potential"]
        works = [t for t in self.terms if t.role == "work"]
        # the summation order of the potential (it fixes the round-off of the residual): terms
        # without a pseudo Hessian first, in their order, then the others
        ordered = sorted(potentials, key=lambda t: "pseudo" in t.hessians)  # a stable sort
        potential = _sum_forms([t.scaled(lf) for t in ordered])
        residual = ufl.derivative(potential, x, test)
        for work in works:
            residual = residual - lf * work.form
        # Dead loads have a potential, -work[x]; a follower pressure has none.
        dead = [ufl.replace(w.form, {test: x}) for w in works if w.conservative]
        dead_line_work = sum(dead) if dead else None
        # Conservative problems minimize a total potential; the line search uses it as merit function.
        total = potential if dead_line_work is None else potential - lf * dead_line_work
        # "adaptive" iterates with the exact Hessian, the one projected out of the plane and the
        # projected one, each where the one before is indefinite (bhem_hpc.model.hessian)
        # "trust_region" models with the exact one, preconditioned by the projected one
        kinds = COMPOSED_HESSIANS.get(self.hessian, (self.hessian,))
        jacobians = {kind: self._jacobian(kind, residual, potentials, works, test, trial) for kind in kinds}
        self.symmetric = all(w.conservative for w in works)
        unknowns = self.in_unknowns
        residual, jacobians = unknowns(residual), {kind: unknowns(j) for kind, j in jacobians.items()}
        total, dead_line_work = unknowns(total), None if dead_line_work is None else unknowns(dead_line_work)
        self.ufl_residual = residual
        reported = {t.name: unknowns(t.form) for t in self.terms if t.reported}
        jit = default_jit_params()
        with compilation_report("the shell model", jit["cache_dir"]):
            self._compile(total, dead_line_work, residual, jacobians, reported, jit)

    def in_unknowns(self, form: ufl.Form) -> ufl.Form:
        """A form written in positions, as a form in the Functions the model holds: the identity,
        except for rational B-splines, whose Functions hold the homogeneous ``Y`` and whose position
        is ``Y / W`` (:meth:`Discretization.position_map`); every position-like Function
        (:attr:`position_functions`) and the form's arguments are replaced, the map being linear."""
        position = self.discretization.position_map()
        if position is None:
            return form
        return ufl.replace(form, {f: position(f) for f in (*self.position_functions, *form.arguments())})

    def _jacobian(self, kind: str, residual, potentials: Sequence[Term], works: Sequence[Term], test, trial):
        """The UFL Jacobian of Hessian ``kind``: the exact one, or each term's replacement of that kind."""
        x, lf = self.x, self.load_factor
        if kind == "exact":
            return ufl.derivative(residual, x, trial)
        kept = [t.scaled(lf) for t in potentials if kind not in t.hessians]
        parts = [ufl.derivative(ufl.derivative(_sum_forms(kept), x, test), x, trial)] if kept else []
        for term in potentials:
            if kind in term.hessians:
                replaced = term.hessians[kind](test, trial)
                parts.append(lf * replaced if term.load_scaled else replaced)
        jacobian = _sum_forms(parts)
        for work in works:
            jacobian = jacobian - lf * ufl.derivative(work.form, x, trial)
        return jacobian

    def _compile(self, total, dead_line_work, residual, jacobians: dict, energies: dict, jit: dict) -> None:
        """The dolfinx forms of the composed UFL forms (JIT-compiled, or loaded from the cache)."""
        self.potential_form = fem.form(total, jit_params=jit) if self.symmetric else None
        self.line_load_work_form = None if dead_line_work is None else fem.form(dead_line_work, jit_params=jit)
        self.residual_form = fem.form(residual, jit_params=jit)
        #: the Jacobian of each Hessian kind the model iterates with; ``jacobian_form``: the first, whose
        #: steps are recomputed with the second (if any) where its LDL^T is indefinite
        self.jacobian_forms = {kind: fem.form(j, jit_params=jit) for kind, j in jacobians.items()}
        self.jacobian_form = next(iter(self.jacobian_forms.values()))
        self.energy_forms = {name: fem.form(e, jit_params=jit) for name, e in energies.items()}

    def term_residual_forms(self) -> dict[str, fem.Form]:
        """Each potential's gradient and each work's negative (load factor applied), compiled on first
        use: what a failed solve reports per term."""
        if self._term_residual_forms is None:
            test = ufl.TestFunction(self.discretization.function_space)
            lf = self.load_factor
            forms_by_term = {}
            for term in self.terms:
                if term.role == "potential":
                    forms_by_term[term.name] = ufl.derivative(term.scaled(lf), self.x, test)
                elif term.role == "work":
                    forms_by_term[term.name] = -lf * ufl.replace(term.form, {term.form.arguments()[0]: test})
            jit = default_jit_params()
            with compilation_report("the per-term residuals", jit["cache_dir"]):
                self._term_residual_forms = {name: fem.form(self.in_unknowns(f), jit_params=jit)
                                             for name, f in forms_by_term.items()}  # fmt: skip
        return self._term_residual_forms

    def _build_point_data(self, loads: Loads, point_constraints: Sequence[PointConstraint]) -> None:
        """Point loads, point constraints' basis values, and the nodal constraints' DOFs and values."""
        disc = self.discretization
        # Point loads: basis values at the point times the force, on local open DOFs.
        self._point_load_basis = [disc.point_basis(load.xi1, load.xi2) for load in loads.point_loads]
        self.point_forces = np.array([load.force for load in loads.point_loads], dtype=float).reshape(-1, 3)
        self.point_loads_version = 0
        self._assemble_point_loads()

        # Point constraints: the 16 basis values of the containing patch (on its owning rank only).
        self.point_constraints = tuple(point_constraints)
        self.point_constraint_basis = [disc.point_basis(pc.xi1, pc.xi2) for pc in self.point_constraints]

        # Boundary conditions as owned closed DOFs with initial and target values.
        target = target_surface(self.initial_surface, self.constraints)
        selections = [disc.select_dofs(c.nodes, c.kinds, c.components) for c in self.constraints]
        # a tied control point's own components no longer shape the surface: held where they are;
        # and a held component that follows a root holds its root
        held = _merge(selections)
        selections += [disc.select_dofs(t.nodes, (0,), t.components) for t in self.ties]
        self.constrained = _merge([*selections, disc.tied_roots(held)])
        self.constrained_initial = disc.dof_values(self.initial_surface, self.constrained)
        self.constrained_target = disc.dof_values(target, self.constrained)

    def _assemble_point_loads(self) -> None:
        self.point_load_open = np.zeros_like(self.x.x.array)
        for (blocks, values), force in zip(self._point_load_basis, self.point_forces, strict=True):
            for comp in range(3):
                np.add.at(self.point_load_open, 3 * blocks + comp, values * force[comp])

    # -- loads -----------------------------------------------------------------------------------
    def load_names(self) -> list[str]:
        """The loads :meth:`set_load` can change: ``gravity``, ``pressure``, ``line_load_<i>``,
        ``point_load_<i>``, ``edge_moment_<i>``, ``area_load_<i>`` (those the model was built with)."""
        names = ["gravity"] if self.loads.gravity is not None else []
        names += ["pressure"] if self.loads.pressure is not None else []
        names += [f"line_load_{i}" for i in range(len(self.loads.line_loads))]
        names += [f"point_load_{i}" for i in range(len(self.loads.point_loads))]
        names += [f"edge_moment_{i}" for i in range(len(self.loads.edge_moments))]
        return names + [f"area_load_{i}" for i in range(len(self.loads.area_loads))]

    def set_load(self, name: str, value) -> None:
        """Change a load's magnitude (the load factor still scales it); a solve continues from the
        current state. ``value``: 3 numbers (gravity [m/s^2], line load [N/m], area load [N/m^2])
        or a number (pressure [Pa]).

        Raises:
            ModelError: an unknown load name or a value of the wrong shape.
        """
        constants = {"gravity": getattr(self, "gravity", None), "pressure": getattr(self, "pressure", None)}
        constants |= {f"line_load_{i}": c for i, c in enumerate(getattr(self, "tractions", []))}
        constants |= {f"edge_moment_{i}": c for i, c in enumerate(getattr(self, "edge_moments", []))}
        constants |= {f"area_load_{i}": c for i, c in enumerate(self.area_load_forces)}
        if name not in self.load_names():
            raise ModelError(f"load {name!r} does not exist; this model has {self.load_names()}")
        if name.startswith("point_load_"):
            force = np.asarray(value, dtype=float)
            if force.shape != (3,) or not np.all(np.isfinite(force)):
                raise ModelError(f"load {name!r} must be 3 numbers (finite), got {value!r}")
            self.point_forces[int(name.rsplit("_", 1)[1])] = force
            self._assemble_point_loads()
            self.point_loads_version += 1
            return
        constant = constants[name]
        array = np.asarray(value, dtype=float)
        if array.shape != constant.value.shape or not np.all(np.isfinite(array)):
            shape = "a number" if constant.value.shape == () else "3 numbers"
            raise ModelError(f"load {name!r} must be {shape} (finite), got {value!r}")
        constant.value = array

    def prescribed_values(self, moved: Sequence[NodalConstraint]) -> np.ndarray:
        """Reference-DOF values of the constrained DOFs (``self.constrained``) with the values of the
        ``moved`` constraints (same nodes, kinds and components as some of the model's) written over
        the model's targets: prescribed motions at a time or load factor."""
        target = target_surface(self.initial_surface, [*self.constraints, *moved])
        return self.discretization.dof_values(target, self.constrained)

    # -- state access --------------------------------------------------------------------------
    @property
    def num_dofs(self) -> int:
        """Unknowns of the solver: 3 per closed DOF (Hermite nodal vector or control point)."""
        return 3 * self.discretization.num_closed

    @property
    def rest_diagonal(self) -> float:
        """The diagonal [m] of the bounding box of the rest surface's nodes (tolerances scale with it)."""
        nodes = self.rest_surface.evaluate(*self.rest_surface.grid.node_parameters()).x.reshape(-1, 3)
        return float(np.linalg.norm(nodes.max(axis=0) - nodes.min(axis=0)))

    @property
    def global_open_blocks(self) -> np.ndarray:
        """The global index of each of this rank's open blocks (owned, then ghosts), ``(blocks,)``:
        the names of Hessian blocks that may couple blocks of different ranks."""
        index_map = self.x.function_space.dofmap.index_map
        return np.asarray(index_map.local_to_global(np.arange(index_map.size_local + index_map.num_ghosts,
                                                              dtype=np.int32)), dtype=np.int64)  # fmt: skip

    # -- what the Newton driver asks of every body (a solid answers the same) -----------------
    @property
    def has_potential(self) -> bool:
        """Whether the loads are conservative (no follower pressure): an energy line search applies."""
        return self.potential_form is not None

    @property
    def closed_dofs(self) -> tuple[int, int]:
        """Closed DOFs this rank owns and in all."""
        return 3 * self.discretization.num_owned_closed, 3 * self.discretization.num_closed

    @property
    def closed_is_open(self) -> bool:
        """No seams or ties: the closed DOFs are the open ones."""
        return self.discretization.closed_is_open

    @property
    def open_blocks(self) -> tuple[int, int]:
        """Open blocks this rank owns and its ghosts."""
        index_map = self.x.function_space.dofmap.index_map
        return index_map.size_local, index_map.num_ghosts

    @property
    def open_positions(self) -> np.ndarray:
        """``(open blocks, 3)`` the position on this rank's open blocks (a view)."""
        return self.x.x.array.reshape(-1, 3)

    @property
    def force_scale(self) -> float:
        """``Y h`` times the largest patch size [N]: the scale of the internal forces (their round-off)."""
        grid = self.rest_surface.grid
        return self.material.young * self.material.thickness * max(grid.h1, grid.h2)

    @property
    def linear_scales(self) -> tuple[float, float, float, float]:
        """Density, Young's modulus, Poisson's ratio and the median patch edge [m] (how much the
        mass dominates the stiffness: the choice of linear solver)."""
        nodes = self.rest_surface.nodal[..., 0, :]  # nodes (Hermite) or control points (B-splines)
        edges = [np.linalg.norm(np.diff(nodes, axis=a), axis=-1) for a in (0, 1)]
        element = float(np.median(np.concatenate([e.ravel() for e in edges])))
        material = self.material
        return material.density, material.young, material.poisson, element

    def point_basis(self, xi1: float, xi2: float) -> tuple[np.ndarray, np.ndarray]:
        """The open blocks and basis values of the material point ``(xi1, xi2)`` (on the rank owning
        its patch; empty elsewhere)."""
        return self.discretization.point_basis(xi1, xi2)

    def point_frame_basis(self, xi1: float, xi2: float) -> tuple[np.ndarray, np.ndarray]:
        """The open blocks and basis values ``(3, n)`` of the position and the two tangents of the
        material point ``(xi1, xi2)`` (on the rank owning its patch; empty elsewhere)."""
        return self.discretization.point_frame_basis(xi1, xi2)

    def open_state(self) -> tuple[np.ndarray, np.ndarray | None]:
        """Copies of the position and, in dynamics, the previous position (open layout)."""
        return self.x.x.array.copy(), self.x_previous.x.array.copy() if self.dynamics is not None else None

    def set_open_state(self, position: np.ndarray, previous: np.ndarray | None) -> None:
        self.x.x.array[:] = position
        if previous is not None:
            self.x_previous.x.array[:] = previous

    def gather_raw(self, array: np.ndarray) -> np.ndarray:
        """Collective: an open array as raw DOFs, gathered (checkpoints)."""
        return self.discretization.gather_raw_dofs(array)

    def scatter_raw(self, raw: np.ndarray) -> np.ndarray:
        """Raw DOFs as this rank's open array."""
        return self.discretization.scatter_raw_dofs(raw)

    def point_positions(self, bases: Sequence[tuple[np.ndarray, np.ndarray]]) -> np.ndarray:
        """Collective: positions ``(points, 3)`` at the current state of material points given by their
        ``discretization.point_basis`` (each on the rank owning its patch, so summed over ranks)."""
        local = np.zeros((len(bases), 3))
        positions = self.x.x.array.reshape(-1, 3)
        for k, (blocks, values) in enumerate(bases):
            if len(blocks):
                local[k] = values @ positions[blocks]
        return self.comm.allreduce(local)

    def displacement(self, xi1: float, xi2: float) -> np.ndarray:
        """Collective: the displacement ``(3,)`` of the material point ``(xi1, xi2)`` from the initial
        surface, at the current state."""
        start = self.initial_surface.evaluate(np.array(xi1), np.array(xi2)).x
        return self.point_positions([self.discretization.point_basis(xi1, xi2)])[0] - start

    def set_state(self, surface: HermiteSurface) -> None:
        """Set the position field from a surface."""
        self.x.x.array[:] = self.discretization.surface_to_open(surface)

    def state_surface(self) -> HermiteSurface:
        """Collective: the current position as a surface (on every rank)."""
        return self.discretization.open_to_surface(self.x.x.array)

    def energies(self) -> dict[str, float]:
        """Collective: every built energy term at the current state (load factor not applied).

        ``external_work`` is the work of the dead loads at the current position: gravity, area,
        line and point loads (a follower pressure has no potential and is not included).
        """
        values = {
            name: self.comm.allreduce(fem.assemble_scalar(form), op=MPI.SUM) for name, form in self.energy_forms.items()
        }
        # Point-load contributions sit once, on the rank owning the loaded cell: no double count.
        work = float(np.dot(self.point_load_open, self.x.x.array))
        if self.line_load_work_form is not None:
            work += fem.assemble_scalar(self.line_load_work_form)
        dead_potentials = sum(v for k, v in values.items() if k == "gravity" or k.startswith("area_load_"))
        values["external_work"] = self.comm.allreduce(work, op=MPI.SUM) - dead_potentials
        return values


def _validate(
    rest: HermiteSurface, initial: HermiteSurface, loads: Loads,
    constraints: Sequence[NodalConstraint], hessian: str, quadrature_points: Quadrature, dynamics: Dynamics | None,
    point_constraints: Sequence[PointConstraint], material: Material,
) -> None:  # fmt: skip
    """Every check of a model's definition, before anything is built (raises :class:`ModelError`)."""
    loads.validate()
    if dynamics is not None:
        dynamics.validate()
    if hessian not in HESSIAN_KINDS:
        raise ModelError(f"hessian = {hessian!r}; expected one of {HESSIAN_KINDS}")
    if hessian == "trust_region" and (dynamics is None or loads.pressure is not None):
        raise ModelError("hessian = 'trust_region' minimizes the incremental potential of a time step: it needs "
                         "dynamics and no follower pressure (which has no potential)")  # fmt: skip
    try:
        check_quadrature(quadrature_points, rest.discretization)
    except QuadratureError as error:
        raise ModelError(str(error)) from None
    rest.check_regular(3 if quadrature_points == "reduced" else quadrature_points, name="rest surface")
    _check_energy_models(rest, material)
    if initial.grid != rest.grid or type(initial) is not type(rest) or initial.node_shape != rest.node_shape:
        raise ModelError("initial and rest surfaces have different grids or kinds")
    for c in constraints:
        c.validate(rest.grid, rest.node_shape, rest.kind_count)
    for i, pc in enumerate(point_constraints):
        if not set(pc.components) <= {0, 1, 2} or not pc.components:
            raise ModelError(f"point_constraints[{i}].components = {pc.components!r}; expected a subset of (0, 1, 2)")
        target = pc.target_at(0.0)
        if target.shape != (3,) or not np.all(np.isfinite(target)):
            raise ModelError(f"point_constraints[{i}].target must give 3 finite numbers, got {target!r}")
        rest.grid.locate(np.array(pc.xi1), np.array(pc.xi2))  # raises if outside the surface


def _check_energy_models(rest: HermiteSurface, material: Material) -> None:
    """The material's energy models apply to the rest surface: the quadratic bending energy needs a
    flat rest surface with an affine parametrization, the Baraff-Witkin membrane parametric
    directions that do not degenerate."""
    xi1, xi2 = rest.grid.node_parameters()
    point = rest.evaluate(xi1, xi2)
    size = float(np.ptp(point.x.reshape(-1, 3), axis=0).max())
    if material.bending == "quadratic":
        curved = max(float(np.abs(getattr(point, name)).max()) for name in ("a11", "a12", "a22"))
        normal = np.cross(point.a1, point.a2)
        normal /= np.linalg.norm(normal, axis=-1, keepdims=True)
        bent = float(np.abs(normal - normal.reshape(-1, 3)[0]).max())
        if curved > 1e-9 * max(size, 1e-300) or bent > 1e-9:
            raise ModelError(f"material.bending = 'quadratic' needs a flat rest surface with an affine "
                             f"parametrization (the rest surface's second derivatives reach {curved:.3g}, its "
                             f"normal turns by {bent:.3g}); use material.bending = 'svk'")  # fmt: skip
    if material.membrane == "fbw":
        tangents = np.linalg.norm(np.cross(point.a1, point.a2), axis=-1)
        if tangents.min() <= 1e-12 * max(size, 1e-300) ** 2:
            raise ModelError("material.membrane = 'fbw' needs parametric (warp and weft) directions at every "
                             "point; the rest surface degenerates (a1 x a2 = 0 somewhere); use "
                             "material.membrane = 'svk'")  # fmt: skip


def _sum_forms(summands: Sequence[ufl.Form]) -> ufl.Form:
    """``summands[0] + summands[1] + ...`` in that order."""
    total = summands[0]
    for form in summands[1:]:
        total = total + form
    return total


def _merge(selections: Sequence[ConstrainedDofs]) -> ConstrainedDofs:
    """Union of DOF selections (a DOF named twice appears once)."""
    if not selections:
        empty = np.zeros(0, dtype=np.int64)
        return ConstrainedDofs(empty, empty, np.zeros((0, 2), dtype=np.int64), empty, empty)
    rows = np.concatenate([s.rows for s in selections])
    _, first = np.unique(rows, return_index=True)

    def pick(name: str) -> np.ndarray:
        return np.concatenate([getattr(s, name) for s in selections])[first]

    return ConstrainedDofs(pick("rows"), pick("local"), pick("node"), pick("kind"), pick("component"))

"""The layout's rules: numpy-only geometry and collision, forms on UFL alone, PETSc in PETSc modules,
no import cycle."""

from __future__ import annotations

import ast
import graphlib
from pathlib import Path

import pytest
from helpers import assert_imports_without

PACKAGE = Path(__file__).resolve().parents[1] / "bhem_hpc"
#: The only modules that may import petsc4py (as dolfinx keeps PETSc code in petsc.py files).
PETSC_MODULES = {"solids/petsc.py", "solver/newton.py", "solver/path.py", "solver/problem.py", "solver/petsc.py",
                 "solver/linear_strategy.py", "solver/load_steps.py", "solver/acceleration.py",
                 "solver/trust_region.py", "solver/energy_trust_region.py", "solver/form_terms.py",
                 "solver/hessian_action.py",
                 "contact/petsc.py", "contact/bodies_petsc.py", "bodies/petsc.py", "bodies/shared_petsc.py",
                 "studies/petsc.py"}


@pytest.mark.parametrize(
    ("module", "forbidden"),
    [
        ("bhem_hpc.geometry.surface", ("dolfinx", "petsc4py", "mpi4py", "ufl", "basix")),
        ("bhem_hpc.geometry.trim", ("dolfinx", "petsc4py", "mpi4py", "ufl", "basix")),
        ("bhem_hpc.scene.loader", ("dolfinx", "petsc4py", "ufl", "basix")),
        ("bhem_hpc.collision", ("dolfinx", "petsc4py", "mpi4py", "ufl", "basix")),
        ("bhem_hpc.contact.detection", ("dolfinx", "petsc4py", "mpi4py", "ufl", "basix")),
        ("bhem_hpc.contact.bodies", ("dolfinx", "petsc4py", "mpi4py", "ufl", "basix")),
        ("bhem_hpc.contact.ipc", ("dolfinx", "petsc4py", "mpi4py", "ufl", "basix")),
        ("bhem_hpc.contact.ipc_contribution", ("dolfinx", "petsc4py", "mpi4py", "ufl", "basix")),
        ("bhem_hpc.contact.ipc_setup", ("dolfinx", "petsc4py", "mpi4py", "ufl", "basix")),
        ("bhem_hpc.forms", ("dolfinx", "petsc4py", "mpi4py", "basix")),
        ("bhem_hpc.solver.contributions", ("dolfinx", "petsc4py", "mpi4py", "ufl", "basix")),
        ("bhem_hpc.bodies.layout", ("dolfinx", "petsc4py", "mpi4py", "ufl", "basix")),
    ],
)
def test_geometry_forms_and_collision_import_without_petsc(module, forbidden):
    assert_imports_without(module, forbidden)


def _imported_modules(path: Path) -> set[str]:
    names = set()
    for node in ast.walk(ast.parse(path.read_text())):
        if isinstance(node, ast.Import):
            names.update(alias.name for alias in node.names)
        elif isinstance(node, ast.ImportFrom) and node.module:
            names.add(node.module)
    return names


def test_petsc_is_imported_only_by_petsc_modules():
    importers = {
        str(path.relative_to(PACKAGE))
        for path in PACKAGE.rglob("*.py")
        if any(name.split(".")[0] == "petsc4py" or name == "dolfinx.fem.petsc" for name in _imported_modules(path))
    }
    importers.discard("cli.py")  # petsc4py.init must see the command line's PETSc options first
    assert importers <= PETSC_MODULES, sorted(importers - PETSC_MODULES)


def test_no_dof_index_is_computed_outside_the_discretization():
    """Layout internals of the discretization are not read anywhere else."""
    internals = ("owned_closed_open_block", "closed_of_open", "block_kind", "block_scale", "distinct_node")
    readers = sorted(
        f"{path.relative_to(PACKAGE)}: {name}"
        for path in PACKAGE.rglob("*.py")
        if path.parent.name != "discretization"
        for name in internals
        if f".{name}" in path.read_text()
    )
    assert not readers, readers


def test_every_package_is_installed():
    """pyproject.toml lists every package directory (a wheel holds only the listed ones)."""
    import tomllib

    listed = set(tomllib.loads((PACKAGE.parent / "pyproject.toml").read_text())["tool"]["setuptools"]["packages"])
    found = {"bhem_hpc." + p.parent.relative_to(PACKAGE).as_posix().replace("/", ".")
             for p in PACKAGE.rglob("__init__.py") if p.parent != PACKAGE} | {"bhem_hpc", "bhem_hpc.forms"}  # fmt: skip
    assert listed == found


def _module_name(path: Path) -> str:
    parts = path.relative_to(PACKAGE.parent).with_suffix("").parts
    return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)


def _module_level_imports(path: Path, modules: set[str]) -> set[str]:
    """The package's modules that ``path`` imports when it is loaded: its top-level imports, not
    those under ``if TYPE_CHECKING:`` nor those inside functions (deliberately deferred)."""
    found = set()
    for node in ast.parse(path.read_text()).body:
        if isinstance(node, ast.Import):
            found.update(alias.name for alias in node.names)
        elif isinstance(node, ast.ImportFrom) and node.module:
            # ``from package import module`` imports that module; ``from module import name`` the module
            found.update(f"{node.module}.{alias.name}" if f"{node.module}.{alias.name}" in modules else node.module
                         for alias in node.names)  # fmt: skip
    return found & modules


def test_no_import_cycle():
    """The modules' load-time imports form a directed acyclic graph (a cycle makes the load order
    decide which names exist, as solver/newton.py and solver/problem.py once did)."""
    paths = {_module_name(path): path for path in PACKAGE.rglob("*.py")}
    graph = {name: _module_level_imports(path, set(paths)) - {name} for name, path in paths.items()}
    assert len(graph) > 100 and sum(map(len, graph.values())) > 300  # the graph was read
    try:
        graphlib.TopologicalSorter(graph).prepare()
    except graphlib.CycleError as cycle:
        pytest.fail(f"import cycle: {' -> '.join(cycle.args[1])}")

"""sim_core: Baudet's parametrised mass-spring system (hexahedra, or tetrahedra with ``TetMesh``) and its
finite-element references.

Quick start::

    from sim_core import HexMesh, Material, build_model, solve_static
    mesh = HexMesh.block((10, 10, 10), spacing=0.01)           # 10 cm cube, 1 cm elements
    model = build_model(mesh, Material(5e3, 0.45, 1060), gravity=(0, -9.81, 0))
    control = model.new_control().impose(bottom_nodes, mesh.nodes[bottom_nodes])
    equilibrium = solve_static(model, control)
    solver = make_solver("implicit", model)                    # or a ModelStack(model, N): N worlds
    state, next_state = model.new_state(), model.new_state()
    report = solver.step(state, next_state, control, 0.01)    # 10 ms

All quantities are SI: m, kg, s, Pa, N. Formulas follow docs/physics.md.
"""

from importlib import metadata as _metadata

from . import compiling as _compiling

_compiling.install()  # one message (logger "sim_core.kernels", stderr) when kernels compile, not load from the cache

from .models.material import Material
from .geometry.mesh import HexMesh
from .geometry.tetmesh import TetMesh
from .models.model import Control, Model, State, build_model
from .solvers.static import StaticResult, solve_static, zero_energy_modes
from .models.stack import ModelStack
from .solvers.solver import StepReport
from .solvers.worlds import make_solver

#: The version of pyproject.toml; used when the package runs from a clone that is not installed.
_SOURCE_VERSION = "0.1.0"

try:
    __version__ = _metadata.version("tissue-gym")
except _metadata.PackageNotFoundError:  # a clone on sys.path, not installed
    __version__ = _SOURCE_VERSION

__all__ = [
    "__version__", "Control", "HexMesh", "Material", "Model", "ModelStack", "State", "StaticResult", "StepReport",
    "build_model", "make_solver", "solve_static", "TetMesh", "zero_energy_modes",
]

"""The layers hold: modules a reader can take in (under 1,000 lines), no import cycles (imports made
inside functions included), no private name imported from another module, no compiled kernels in
the environment layer, and the studies (experiments, resolution choice, bench, demo, CLI) above the
physics: no physics module imports them. The scripts beside the packages (docs/, training/,
benchmarks/) are held to the same size. Read from the source with ``ast``, nothing imported."""

import ast
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
PACKAGES = ("sim_core", "tissue_env")
MAX_LINES = 1000
#: folders of scripts and their helper modules whose size is checked (not their imports)
SCRIPT_FOLDERS = ("docs", "training", "benchmarks")


def _modules():
    """{dotted module name: path} of every module of the packages."""
    modules = {}
    for package in PACKAGES:
        for path in sorted((ROOT / package).rglob("*.py")):
            parts = path.relative_to(ROOT).with_suffix("").parts
            name = ".".join(parts[:-1] if parts[-1] == "__init__" else parts)
            modules[name] = path
    return modules


MODULES = _modules()


def _imports(name, path):
    """[(imported module, [names], is_function_level)] of the module ``name`` at ``path``; relative
    imports resolved."""
    tree = ast.parse(path.read_text())
    package = name if path.name == "__init__.py" else name.rpartition(".")[0]
    function_level = set()
    for node in ast.walk(tree):
        if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef)):
            function_level.update(id(child) for child in ast.walk(node) if child is not node)
    found = []
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            for alias in node.names:
                found.append((alias.name, [], id(node) in function_level))
        elif isinstance(node, ast.ImportFrom):
            base = node.module or ""
            if node.level:
                anchor = package.split(".")[: len(package.split(".")) - node.level + 1]
                base = ".".join(anchor + ([base] if base else []))
            names = [alias.name for alias in node.names]
            # "from . import kernels" imports the module sim_core.kernels
            submodules = [f"{base}.{n}" for n in names if f"{base}.{n}" in MODULES]
            if submodules:
                found.extend((module, [], id(node) in function_level) for module in submodules)
                names = [n for n in names if f"{base}.{n}" not in MODULES]
            if names:
                found.append((base, names, id(node) in function_level))
    return found


GRAPH = {name: _imports(name, path) for name, path in MODULES.items()}


def _assert_short(path):
    lines = len(path.read_text().splitlines())
    assert lines < MAX_LINES, f"{path.relative_to(ROOT)} has {lines} lines: split it along its seams"


@pytest.mark.parametrize("name", sorted(MODULES))
def test_every_module_is_under_a_thousand_lines(name):
    _assert_short(MODULES[name])


SCRIPTS = sorted(path.relative_to(ROOT).as_posix() for folder in SCRIPT_FOLDERS
                 for path in (ROOT / folder).rglob("*.py"))


@pytest.mark.parametrize("script", SCRIPTS)
def test_every_script_is_under_a_thousand_lines(script):
    _assert_short(ROOT / script)


def test_every_script_folder_holds_scripts():
    """A folder renamed or gone fails here instead of leaving the size check above with nothing to check."""
    empty = [folder for folder in SCRIPT_FOLDERS if not any(s.startswith(folder + "/") for s in SCRIPTS)]
    assert not empty, empty


def test_the_size_check_fails_on_a_missing_file():
    """A script the size check cannot read fails it (it is not skipped as short)."""
    with pytest.raises(FileNotFoundError):
        _assert_short(ROOT / "benchmarks" / "no_such_script.py")


def test_no_import_cycles_between_modules():
    edges = {name: {module for module, _, _ in GRAPH[name] if module in MODULES and module != name}
             for name in MODULES}
    # a package's __init__ re-exports its modules; an import of the package from one of its own
    # modules would be a cycle, any other import of it is an edge to its modules
    state, stack, cycles = {}, [], []

    def visit(node):
        state[node] = "open"
        stack.append(node)
        for target in sorted(edges[node]):
            if state.get(target) == "open":
                cycles.append(stack[stack.index(target):] + [target])
            elif target not in state:
                visit(target)
        stack.pop()
        state[node] = "done"

    for name in sorted(edges):
        if name not in state:
            visit(name)
    # a package importing its own submodules (the __init__ re-exports) is not a cycle by itself
    real = [cycle for cycle in cycles
            if not all(a == b.rpartition(".")[0] or b == a.rpartition(".")[0] for a, b in zip(cycle, cycle[1:]))]
    assert not real, "import cycles: " + "; ".join(" -> ".join(cycle) for cycle in real)


def _private(name):
    """A private name: a leading underscore, but not a dunder such as ``__version__``."""
    return name.startswith("_") and not (name.startswith("__") and name.endswith("__"))


def test_no_private_name_is_imported_from_another_module():
    offending = [f"{name} imports {', '.join(n for n in names if _private(n))} from {module}"
                 for name in MODULES for module, names, _ in GRAPH[name]
                 if module in MODULES and module != name and any(_private(n) for n in names)]
    assert not offending, "; ".join(offending)


def test_the_environment_layer_holds_no_compiled_kernels():
    offending = [name for name in MODULES if name.startswith("tissue_env")
                 for module, _, _ in GRAPH[name] if module.split(".")[0] == "numba"]
    assert not offending, f"numba imported by {sorted(set(offending))}: kernels belong in sim_core.kernels"


def test_the_physics_does_not_import_the_studies():
    offending = [f"{name} imports {module}" for name in MODULES
                 if name.startswith("sim_core") and not name.startswith("sim_core.studies")
                 and name not in ("sim_core.experiments", "sim_core.resolution")  # the studies' public names
                 for module, _, _ in GRAPH[name] if module.startswith("sim_core.studies")]
    assert not offending, "; ".join(offending)


def test_the_physics_does_not_import_the_environments():
    """sim_core (its studies and commands included) stands below tissue_env: the kernels' warm-up over
    the environments is tissue_env's own command (``tissue-gym-warmup``)."""
    offending = [f"{name} imports {module}" for name in MODULES if name.startswith("sim_core")
                 for module, _, _ in GRAPH[name] if module.split(".")[0] in ("tissue_env", "training")]
    assert not offending, "; ".join(offending)

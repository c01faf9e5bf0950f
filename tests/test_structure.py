"""The rules of the package structure (docs/architecture.md), checked on the import graph read from the source.

Every import counts, including those inside functions: an import deferred into a function is still a dependency.
"""

import ast
from pathlib import Path

import pytest

PACKAGE = Path(__file__).resolve().parents[1] / "src" / "canter"

# Layers from the bottom up: a module may import its own layer and the layers below it, never one above.
LAYERS = ("foundation", "envs", "config", "core", "algos", "training", "use", "orchestrate", "cli")
# Errors, safe file writes, parsing that survives deep nesting, the run folder's names, stop signals, and the
# packages that only hold shipped TOML data.
FOUNDATION = {
    "canter.errors",
    "canter.files",
    "canter.parsing",
    "canter.run_layout",
    "canter.signals",
    "canter.presets",
    "canter.data",
}
# The package's front doors (its API and `python -m canter`) and the README generator sit above everything.
TOP = {"canter", "canter.__main__", "canter.docs"}
ENV_LIBRARIES = {"gymnasium", "envpool", "mujoco", "dm_control"}


def _module_name(path: Path) -> str:
    parts = path.relative_to(PACKAGE.parent).with_suffix("").parts
    return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)


def _imports(path: Path) -> set[str]:
    found = set()
    for node in ast.walk(ast.parse(path.read_text())):
        if isinstance(node, ast.Import):
            found |= {alias.name for alias in node.names}
        elif isinstance(node, ast.ImportFrom) and node.module and node.level == 0:
            found.add(node.module)
            found |= {f"{node.module}.{alias.name}" for alias in node.names}
    return found


GRAPH = {_module_name(p): _imports(p) for p in sorted(PACKAGE.rglob("*.py"))}
MODULES = set(GRAPH)


def _canter_imports(module: str) -> set[str]:
    return {name for name in GRAPH[module] if name in MODULES and name != module}


def _layer(module: str) -> int | None:
    if module in TOP:
        return None
    if module in FOUNDATION:
        return 0
    return LAYERS.index(module.split(".")[1])


def test_every_module_sits_in_a_layer():
    for module in MODULES:
        assert module in TOP or module in FOUNDATION or module.split(".")[1] in LAYERS, module


@pytest.mark.parametrize("module", sorted(MODULES - TOP))
def test_no_module_imports_a_layer_above_its_own(module):
    own = _layer(module)
    above = [name for name in _canter_imports(module) if name not in TOP and _layer(name) > own]
    assert not above, f"{module} ({LAYERS[own]}) imports {above}"


def test_config_never_imports_an_algorithm():
    for module in MODULES:
        if module.startswith("canter.config"):
            assert not [n for n in _canter_imports(module) if n.startswith("canter.algos")], module


def test_no_env_library_below_the_use_layer():
    for module in MODULES:
        if module.split(".")[1:2] and module.split(".")[1] in ("algos", "core", "training", "config"):
            libraries = {name.split(".")[0] for name in GRAPH[module]} & ENV_LIBRARIES
            assert not libraries, f"{module} imports {libraries}"


def test_nothing_outside_the_cli_imports_it():
    for module in MODULES:
        if not module.startswith("canter.cli") and module != "canter.__main__":
            assert not [n for n in _canter_imports(module) if n.startswith("canter.cli")], module


def test_the_import_graph_has_no_cycles_between_layers():
    # Within the layers the package graph must also be acyclic at the level of modules, deferred imports
    # included (an import moved into a function hides a cycle; it does not remove it).
    edges = {m: {n for n in _canter_imports(m) if n not in TOP and not m.startswith(n + ".")} for m in MODULES - TOP}
    state: dict[str, int] = {}

    def visit(module: str, path: list[str]) -> None:
        state[module] = 1
        for nxt in sorted(edges.get(module, ())):
            if state.get(nxt) == 1:
                raise AssertionError("import cycle: " + " -> ".join(path[path.index(nxt) :] + [nxt]))
            if nxt not in state:
                visit(nxt, path + [nxt])
        state[module] = 2

    for module in sorted(edges):
        if module not in state:
            visit(module, [module])


def test_one_rule_decides_which_runs_are_seeds_of_one_experiment():
    defining = [
        m
        for m in MODULES
        for node in ast.walk(
            ast.parse(
                (PACKAGE.parent / (m.replace(".", "/") + ".py")).read_text()
                if (PACKAGE.parent / (m.replace(".", "/") + ".py")).exists()
                else ""
            )
        )
        if isinstance(node, ast.FunctionDef) and node.name in ("experiment_key", "flat_config")
    ]
    assert sorted(set(defining)) == ["canter.config.experiment"]


def test_building_a_config_imports_neither_jax_nor_an_env_library():
    import subprocess
    import sys

    code = (
        "import sys, canter; canter.build_config('Hopper-v5', algo='sac'); canter.build_config('Hopper-v5'); "
        "print(sorted(m for m in ('jax', 'gymnasium', 'envpool', 'mujoco') if m in sys.modules))"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout
    assert out.strip() == "[]"


def test_train_refuses_a_bad_config_before_it_imports_jax():
    import subprocess
    import sys

    code = (
        "import sys; from canter.cli.main import main; "
        "codes = [main(['train', 'Hopper-v5', '--algo', 'ppx']), main(['train', 'Hopper-v5', '--set', 'ppo.lr=x'])]; "
        "print(codes, 'jax' in sys.modules)"
    )
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert done.stdout.strip() == "[2, 2] False"
    assert "unknown algorithm 'ppx'" in done.stderr

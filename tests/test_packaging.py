"""What a `pip install canter` user gets: every module canter imports comes from a distribution its pyproject
declares (so that it is pinned), the package runs as `python -m canter`, and it ships its type marker."""

import ast
import importlib.metadata
import re
import subprocess
import sys
import tomllib
from pathlib import Path

import canter

ROOT = Path(__file__).resolve().parents[1]
SOURCE = ROOT / "src" / "canter"


def _imported_top_level_modules() -> set[str]:
    modules = set()
    for path in SOURCE.rglob("*.py"):
        for node in ast.walk(ast.parse(path.read_text())):
            if isinstance(node, ast.Import):
                modules.update(alias.name.split(".")[0] for alias in node.names)
            elif isinstance(node, ast.ImportFrom) and node.level == 0 and node.module:
                modules.add(node.module.split(".")[0])
    return modules - set(sys.stdlib_module_names) - {"canter"}


def _declared_distributions() -> set[str]:
    project = tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]
    requirements = list(project["dependencies"])
    for extra in project["optional-dependencies"].values():
        requirements += extra
    names = {re.match(r"[A-Za-z0-9_.-]+", requirement).group(0) for requirement in requirements}
    return {_normalized(name) for name in names}


def _normalized(name: str) -> str:
    return re.sub(r"[-_.]+", "-", name).lower()


def test_every_module_canter_imports_comes_from_a_declared_and_pinned_distribution():
    providers = importlib.metadata.packages_distributions()
    declared = _declared_distributions()
    undeclared = {
        module: providers.get(module)
        for module in _imported_top_level_modules()
        if not {_normalized(name) for name in providers.get(module, [])} & declared
    }
    assert undeclared == {}


def test_every_requirement_is_pinned():
    project = tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]
    requirements = list(project["dependencies"])
    requirements += [r for extra in project["optional-dependencies"].values() for r in extra]
    unpinned = [r for r in requirements if "==" not in r and not r.startswith("canter[")]
    assert unpinned == []


def test_python_dash_m_canter_is_the_cli():
    done = subprocess.run([sys.executable, "-m", "canter", "--version"], capture_output=True, text=True, timeout=60)
    assert done.returncode == 0, done.stderr
    assert done.stdout.strip() == f"canter {canter.__version__}"


def test_the_package_ships_its_type_marker_and_licence():
    assert (SOURCE / "py.typed").is_file()
    project = tomllib.loads((ROOT / "pyproject.toml").read_text())
    assert "py.typed" in project["tool"]["setuptools"]["package-data"]["canter"]
    assert (ROOT / "LICENSE").read_text().startswith("MIT License")
    assert canter.__version__ == project["project"]["version"]

"""Benchmark and report scripts are plain files, not a package: tests load them by path."""

import importlib.util
import sys
from pathlib import Path
from types import ModuleType

BENCHMARKS = Path(__file__).resolve().parents[1] / "benchmarks"


def load_script(name: str, path: Path) -> ModuleType:
    """The script at `path`, executed as the module `name`; sys.modules holds it, since dataclasses look their
    module up there."""
    spec = importlib.util.spec_from_file_location(name, path)
    assert spec and spec.loader, f"no module at {path}"
    module = importlib.util.module_from_spec(spec)
    sys.modules[name] = module
    spec.loader.exec_module(module)
    return module

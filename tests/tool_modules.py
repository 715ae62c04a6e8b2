"""Imports a script of tools/ or experiments/ as a module, for the tests of those scripts (which
are not in the package: each imports only the installed package, never another script)."""

from __future__ import annotations

import importlib.util
import sys
from pathlib import Path
from types import ModuleType

ROOT = Path(__file__).resolve().parent.parent
TOOLS = ROOT / "tools"
EXPERIMENTS = ROOT / "experiments"


def load_script(path: Path) -> ModuleType:
    """The script at `path`, imported under its stem (registered in sys.modules, as dataclasses
    need)."""
    spec = importlib.util.spec_from_file_location(path.stem, path)
    module = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = module
    spec.loader.exec_module(module)
    return module


def load_tool(name: str) -> ModuleType:
    """tools/<name>.py as a module."""
    return load_script(TOOLS / f"{name}.py")


def load_experiment(page: str, name: str) -> ModuleType:
    """experiments/<page>/<name>.py (the script that regenerates data of docs/<page>.md)."""
    return load_script(EXPERIMENTS / page / f"{name}.py")

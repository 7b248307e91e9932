"""Importing the scripts of flow/ (not a package) in tests, each under its own module name."""

from __future__ import annotations

import importlib.util
import sys
from pathlib import Path

FLOW = Path(__file__).resolve().parents[2] / "flow"


def load_script(name: str):
    """flow/<name>.py as a module (flow/ goes on the path first, for the scripts' own imports)."""
    if str(FLOW) not in sys.path:
        sys.path.insert(0, str(FLOW))
    spec = importlib.util.spec_from_file_location(f"flow_{name}", FLOW / f"{name}.py")
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod

"""Importing and running the scripts of flow/ (not a package) in tests, each under its own module name."""

from __future__ import annotations

import importlib.util
import os
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
FLOW = ROOT / "flow"


def load_script(name: str):
    """flow/<name>.py as a module (flow/ goes on the path first, for the scripts' own imports)."""
    if str(FLOW) not in sys.path:
        sys.path.insert(0, str(FLOW))
    spec = importlib.util.spec_from_file_location(f"flow_{name}", FLOW / f"{name}.py")
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


def run_script(name: str, *args, timeout: float = 300) -> subprocess.CompletedProcess:
    """``python flow/<name>.py ARGS`` in its own process, as a user runs it (this checkout's lfusd first
    on its path), its output captured."""
    env = dict(os.environ, PYTHONPATH=os.pathsep.join([str(ROOT), os.environ.get("PYTHONPATH", "")]))
    return subprocess.run([sys.executable, str(FLOW / f"{name}.py"), *map(str, args)], env=env, capture_output=True, text=True,
                          timeout=timeout)


def run_main(name: str, capsys, *args) -> tuple[int, str]:
    """flow/<name>.py's main in this process, as its command line runs it: (exit code, stderr)."""
    mod = load_script(name)
    code = mod.training.main_wrapper(mod.NAME, mod.main, [str(a) for a in args])
    return code, capsys.readouterr().err

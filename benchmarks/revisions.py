"""Modules of this tree's ``lfusd`` as committed at a git revision, loaded beside the tree's own:
what the benchmarks' ``--before REV`` compares against (one place for both bench_verify.py and
bench_baselines.py)."""

from __future__ import annotations

import hashlib
import importlib.util
import subprocess
import sys
import tempfile
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def source_at(rev: str, relpath: str) -> str:
    """The text of ``relpath`` (from the repository root) at git revision ``rev``."""
    return subprocess.run(["git", "-C", str(ROOT), "show", f"{rev}:{relpath}"], capture_output=True, text=True, check=True).stdout


def tag(rev: str) -> str:
    """``rev`` as a fragment of a module name."""
    return "".join(c if c.isalnum() else "_" for c in rev)


def stored(text: str, name: str) -> Path:
    """``text`` as file ``name`` in a temporary folder named by its content (one per content, reused:
    numba's cache lies next to the file and outlives the run)."""
    folder = Path(tempfile.gettempdir()) / f"lfusd_bench_{hashlib.sha1(text.encode()).hexdigest()[:12]}"
    folder.mkdir(exist_ok=True)
    path = folder / name
    if not path.is_file() or path.read_text() != text:
        path.write_text(text)
    return path


def load(name: str, path: Path, package: str):
    """The module at ``path`` as ``name`` inside ``package`` (its relative imports resolve to this tree's modules)."""
    spec = importlib.util.spec_from_file_location(name, path)
    mod = importlib.util.module_from_spec(spec)
    mod.__package__ = package
    sys.modules[name] = mod
    spec.loader.exec_module(mod)
    return mod


def module_at(rev: str, package: str, name: str, source: str | None = None):
    """Module ``package.name`` as committed at ``rev`` (or ``source`` given for it), loaded as
    ``package._name_at_REV`` beside this tree's (one leading underscore: a name with two would be
    mangled where a class body imports it)."""
    if source is None:
        source = source_at(rev, f"{package.replace('.', '/')}/{name}.py")
    return load(f"{package}._{name.lstrip('_')}_at_{tag(rev)}", stored(source, f"{name}.py"), package)

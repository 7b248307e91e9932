"""The package's import graph follows the data flow: stage (author) -> render -> raw passes
(data) -> ground truth (truth) -> evaluation, with the contract (keys, layout, camera) below all.

Every import statement of every module counts, module-level or inside a function."""

from __future__ import annotations

import ast
from pathlib import Path

PACKAGE = Path(__file__).resolve().parents[1] / "lfusd"

BASE = {"errors", "keys", "layout", "camera", "processes", "cpu_account"}
# Which parts of lfusd each part may import (a part is a subpackage or a top-level module).
ALLOWED = {
    "errors": set(),
    "keys": {"errors"},
    "layout": {"errors"},
    "camera": {"errors"},
    "processes": set(),
    "cpu_account": set(),
    "data": BASE | {"data"},
    "author": BASE | {"author"},
    "truth": BASE | {"data", "truth", "author"},  # verify traces motion on the stage itself
    "evaluation": BASE | {"data", "evaluation"},
    "render": BASE | {"author", "data", "truth", "render"},
    "torch": BASE | {"data"},
    # The rig study is an experiment over the whole pipeline: it authors rigs, renders them, reads
    # the dataset and scores it, so it sits above author, render, data and evaluation, like the
    # commands (and, like everything, it does not import them).
    "study": BASE | {"author", "render", "data", "evaluation", "study"},
    # A dataset recipe orchestrates the whole pipeline (generate, render, verify, measure), like the
    # commands, but below them: the CLI calls it, it calls no command.
    "recipe": BASE | {"author", "render", "data", "truth", "recipe"},
    "commands": None,  # the CLI may call anything
    "cli": None,
    "__init__": None,  # the facade (lazy)
    "__main__": {"cli"},
}


def part_of(module: str) -> str:
    return module.split(".")[1] if module.count(".") >= 1 else "__init__"


def _is_module(dotted: str) -> bool:
    path = PACKAGE.parent / dotted.replace(".", "/")
    return path.is_dir() or path.with_suffix(".py").is_file()


def imports(path: Path) -> list[tuple[int, str]]:
    """(line, absolute module) of every import in one file of the package."""
    package = list(path.relative_to(PACKAGE.parent).parts[:-1])
    out = []
    for node in ast.walk(ast.parse(path.read_text())):
        if isinstance(node, ast.Import):
            out += [(node.lineno, a.name) for a in node.names]
        elif isinstance(node, ast.ImportFrom):
            base = package[: len(package) - node.level + 1] if node.level else []
            mod = ".".join(base + ([node.module] if node.module else []))
            out.append((node.lineno, mod))
            # `from lfusd import data` or `from . import motion` imports a module by name
            out += [(node.lineno, f"{mod}.{a.name}") for a in node.names if mod.startswith("lfusd") and _is_module(f"{mod}.{a.name}")]
    return out


def modules():
    for path in sorted(PACKAGE.rglob("*.py")):
        rel = path.relative_to(PACKAGE.parent).with_suffix("")
        name = ".".join(rel.parts[:-1] if rel.name == "__init__" else rel.parts)
        yield path, name


def test_imports_follow_the_data_flow():
    bad = []
    for path, name in modules():
        allowed = ALLOWED[part_of(name) if name != "lfusd" else "__init__"]
        if allowed is None:
            continue
        for line, mod in imports(path):
            if mod == "lfusd" or not mod.startswith("lfusd."):
                continue
            target = mod.split(".")[1]
            if target not in allowed | {part_of(name)}:
                bad.append(f"{path.relative_to(PACKAGE.parent)}:{line} imports {mod}")
    assert not bad, "\n".join(bad)


def test_only_the_render_worker_imports_bpy_and_nothing_imports_the_commands():
    seen_bpy = []
    for path, name in modules():
        for line, mod in imports(path):
            if mod.split(".")[0] == "bpy":
                seen_bpy.append(name)
            if mod.startswith("lfusd.commands") and part_of(name) not in ("commands", "cli"):
                raise AssertionError(f"{name}:{line} imports {mod}: the CLI sits on top, nothing imports it")
    assert seen_bpy == ["lfusd.render.worker"]


def test_reading_a_dataset_needs_neither_pxr_nor_bpy_nor_torch():
    for path, name in modules():
        if part_of(name) in ("data", "keys", "layout", "camera", "errors") and name != "lfusd.data.torch":
            heavy = [m for _, m in imports(path) if m.split(".")[0] in ("pxr", "bpy", "torch")]
            assert not heavy, (name, heavy)

"""The package's import graph follows the data flow: stage (author) -> render -> raw passes
(data) -> ground truth (truth) -> evaluation, with the contract (keys, layout, camera) below all.

Every import statement of every module counts, module-level or inside a function, and so does
every name taken from the ``lfusd`` facade (``from .. import Dataset`` imports lfusd.data.dataset)."""

from __future__ import annotations

import ast
from pathlib import Path

PACKAGE = Path(__file__).resolve().parents[1] / "lfusd"

BASE = {"errors", "keys", "layout", "camera", "processes", "files", "cpu_account"}
# Which parts of lfusd each part may import (a part is a subpackage or a top-level module).
ALLOWED = {
    "errors": set(),
    "keys": {"errors"},
    "layout": {"errors"},
    "camera": {"errors"},
    "processes": set(),
    "files": set(),
    "cpu_account": set(),
    "data": BASE | {"data"},
    "author": BASE | {"author"},
    "truth": BASE | {"data", "truth", "author"},  # verify traces motion on the stage itself
    "evaluation": BASE | {"data", "evaluation", "exports"},  # scoring an export reads it back with its format's reader
    # Export formats read a dataset (anything with Dataset's interface); the KITTI masks use truth's stereo visibility.
    "exports": BASE | {"data", "truth", "exports"},
    "render": BASE | {"author", "data", "truth", "render"},
    "torch": BASE | {"data"},
    # The rig study is an experiment over the whole pipeline: it authors rigs, renders them, reads
    # the dataset and scores it, so it sits above author, render, data and evaluation, like the
    # commands (and, like everything, it does not import them).
    "study": BASE | {"author", "render", "data", "evaluation", "study"},
    # A dataset recipe orchestrates the whole pipeline (generate, render, verify, measure), like the
    # commands, but below them: the CLI calls it, it calls no command.
    "recipe": BASE | {"author", "render", "data", "truth", "recipe"},
    # The benchmark makes a recipe's dataset, splits it, and scores submissions with evaluation's metrics.
    "bench": BASE | {"author", "data", "recipe", "evaluation", "bench"},
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


def facade() -> dict[str, str]:
    """The module behind each name of the ``lfusd`` facade (its lazy table, read from lfusd/__init__.py)."""
    for node in ast.walk(ast.parse((PACKAGE / "__init__.py").read_text())):
        if isinstance(node, ast.Assign) and any(isinstance(t, ast.Name) and t.id == "_LAZY" for t in node.targets):
            table = {name: module for name, (module, _) in ast.literal_eval(node.value).items()}
            return {**table, "LfusdError": "lfusd.errors"}
    raise AssertionError("lfusd/__init__.py has no _LAZY table")


def imports(path: Path, source: str | None = None) -> list[tuple[int, str]]:
    """(line, absolute module) of every import in one file of the package (``source``: its text,
    default read from ``path``). A name taken from the facade counts as an import of its module."""
    package = list(path.relative_to(PACKAGE.parent).parts[:-1])
    names = facade()
    out = []
    tree = ast.parse(path.read_text() if source is None else source)
    bare = False  # `import lfusd`: then every `lfusd.NAME` of the facade counts
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            out += [(node.lineno, a.name) for a in node.names]
            bare |= any(a.name == "lfusd" and a.asname is None for a in node.names)
        elif isinstance(node, ast.ImportFrom):
            base = package[: len(package) - node.level + 1] if node.level else []
            mod = ".".join(base + ([node.module] if node.module else []))
            out.append((node.lineno, mod))
            # `from lfusd import data` or `from . import motion` imports a module by name
            out += [(node.lineno, f"{mod}.{a.name}") for a in node.names if mod.startswith("lfusd") and _is_module(f"{mod}.{a.name}")]
            if mod == "lfusd":  # `from .. import Dataset`: the facade's module
                out += [(node.lineno, names[a.name]) for a in node.names if a.name in names]
    if bare:
        out += [(node.lineno, names[node.attr]) for node in ast.walk(tree) if isinstance(node, ast.Attribute)
                and isinstance(node.value, ast.Name) and node.value.id == "lfusd" and node.attr in names]
    return out


def violations(path: Path, name: str, source: str | None = None) -> list[str]:
    """The imports of module ``name`` (file ``path``) that cross the layers of :data:`ALLOWED`."""
    allowed = ALLOWED[part_of(name) if name != "lfusd" else "__init__"]
    if allowed is None:
        return []
    bad = []
    for line, mod in imports(path, source):
        if mod == "lfusd" or not mod.startswith("lfusd."):
            continue
        target = mod.split(".")[1]
        if target not in allowed | {part_of(name)}:
            bad.append(f"{path.relative_to(PACKAGE.parent)}:{line} imports {mod}")
    return bad


def modules():
    for path in sorted(PACKAGE.rglob("*.py")):
        rel = path.relative_to(PACKAGE.parent).with_suffix("")
        name = ".".join(rel.parts[:-1] if rel.name == "__init__" else rel.parts)
        yield path, name


def test_imports_follow_the_data_flow():
    bad = [v for path, name in modules() for v in violations(path, name)]
    assert not bad, "\n".join(bad)


def test_imports_through_the_facade_are_seen():
    """`from .. import Dataset` in lfusd/author imports the reader (data), which author may not;
    `import lfusd` then `lfusd.verify(...)` in lfusd/data imports truth. Both fail the layering."""
    author = PACKAGE / "author" / "probe.py"
    assert violations(author, "lfusd.author.probe", "from .. import Dataset\n") == ["lfusd/author/probe.py:1 imports lfusd.data.dataset"]
    assert violations(author, "lfusd.author.probe", "def f():\n    from lfusd import LfusdError, render_frame\n") == \
        ["lfusd/author/probe.py:2 imports lfusd.render.job"]
    data = PACKAGE / "data" / "probe.py"
    assert violations(data, "lfusd.data.probe", "import lfusd\n\ndef f(out):\n    return lfusd.verify(out)\n") == \
        ["lfusd/data/probe.py:4 imports lfusd.truth.verify"]
    assert violations(data, "lfusd.data.probe", "from lfusd import LfusdError, __version__\n") == []  # the base, the facade's constant


def test_only_the_render_worker_imports_bpy_and_nothing_imports_the_commands():
    seen_bpy = []
    for path, name in modules():
        for line, mod in imports(path):
            if mod.split(".")[0] == "bpy":
                seen_bpy.append(name)
            if mod.startswith("lfusd.commands") and part_of(name) not in ("commands", "cli"):
                raise AssertionError(f"{name}:{line} imports {mod}: the CLI sits on top, nothing imports it")
            # the Infinigen runner is a script for Infinigen's own interpreter (its bpy 4.2), never imported
            assert mod != "lfusd.author.infinigen_runner", f"{name}:{line} imports the Infinigen runner; run it as a script"
    assert sorted(set(seen_bpy)) == ["lfusd.author.infinigen_runner", "lfusd.render.worker"]


def test_reading_a_dataset_needs_neither_pxr_nor_bpy_nor_torch():
    for path, name in modules():
        if part_of(name) in ("data", "keys", "layout", "camera", "errors") and name != "lfusd.data.torch":
            heavy = [m for _, m in imports(path) if m.split(".")[0] in ("pxr", "bpy", "torch")]
            assert not heavy, (name, heavy)



def _facade_imports(path: Path, text: str) -> list[tuple[int, str]]:
    """(line, name) of each facade name (``lfusd.Dataset``, ``lfusd.render_video``, ...) a module of
    the package imports from ``lfusd`` itself (``from lfusd import X``, ``from .. import X``), and
    ``(line, "*")`` for a plain ``import lfusd``, through which every facade name can be reached."""
    package = list(path.relative_to(PACKAGE.parent).parts[:-1])
    out = []
    for node in ast.walk(ast.parse(text)):
        if isinstance(node, ast.Import):
            out += [(node.lineno, "*") for a in node.names if a.name == "lfusd"]
        elif isinstance(node, ast.ImportFrom):
            base = package[: len(package) - node.level + 1] if node.level else []
            if ".".join(base + ([node.module] if node.module else [])) == "lfusd":
                out += [(node.lineno, a.name) for a in node.names if not _is_module(f"lfusd.{a.name}")]
    return out


def facade_violations(sources) -> list[str]:
    """The facade (lfusd/__init__.py) loads its names lazily from their modules: importing one from
    inside the package imports that module and must follow the data flow like any other import;
    ``import lfusd`` is refused (it reaches every part at once). ``sources``: (path, module, text)."""
    import lfusd

    bad = []
    for path, name, text in sources:
        allowed = ALLOWED[part_of(name) if name != "lfusd" else "__init__"]
        if allowed is None:
            continue
        for line, attr in _facade_imports(path, text):
            where = f"{path.relative_to(PACKAGE.parent)}:{line}"
            if attr == "*":
                bad.append(f"{where} imports lfusd itself; import the module that owns the name")
            elif attr in lfusd._LAZY:
                owner = lfusd._LAZY[attr][0]
                if part_of(owner) not in allowed | {part_of(name)}:
                    bad.append(f"{where} imports lfusd.{attr}, that is {owner}")
            elif attr not in ("__version__", "LfusdError"):
                bad.append(f"{where} imports lfusd.{attr}, which the facade does not have")
    return bad


def test_facade_imports_follow_the_data_flow_too():
    bad = facade_violations((path, name, path.read_text()) for path, name in modules())
    assert not bad, "\n".join(bad)


def test_the_facade_check_sees_facade_imports():
    """Not blind: an `author` module importing lfusd.Dataset (lfusd.data.dataset) is caught through
    either spelling, as is `import lfusd`; a `data` module may import it."""
    text = "from .. import Dataset\nfrom lfusd import render_video\nimport lfusd\nfrom lfusd import __version__, keys\n"
    bad = facade_violations([(PACKAGE / "author" / "probe.py", "lfusd.author.probe", text)])
    assert [b.split(" ", 1)[0] for b in bad] == ["lfusd/author/probe.py:1", "lfusd/author/probe.py:2", "lfusd/author/probe.py:3"], bad
    assert "lfusd.data.dataset" in bad[0] and "lfusd.render.job" in bad[1]
    assert facade_violations([(PACKAGE / "data" / "probe.py", "lfusd.data.probe", "from .. import Dataset\n")]) == []


def test_no_import_cycle_between_modules():
    """Issue 39.21: no two modules import each other, directly or round a loop (deferred imports
    inside functions count); a package and its own submodules are one unit."""
    names = {name: path for path, name in modules()}
    graph: dict[str, set[str]] = {}
    for name, path in names.items():
        graph[name] = set()
        for _, mod in imports(path):
            while mod and mod not in names:
                mod = mod.rpartition(".")[0]
            own = mod.startswith(name + ".") or name.startswith(mod + ".")  # a package and its submodule
            if mod and mod != name and not own:
                graph[name].add(mod)

    def reaches(start: str, goal: str) -> bool:
        seen, todo = set(), [start]
        while todo:
            m = todo.pop()
            if m == goal:
                return True
            if m not in seen:
                seen.add(m)
                todo += graph[m]
        return False

    cycles = sorted(f"{a} -> {b} -> ... -> {a}" for a in graph for b in graph[a] if reaches(b, a))
    assert not cycles, "\n".join(cycles)

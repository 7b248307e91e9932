"""The render job is one pass down (issue 39 item 21): `render_video` calls plan, open the folder,
run, derive and certify in that order from one function, hands no closure down to be called back,
and `lfusd render-video` calls one library function."""

from __future__ import annotations

import ast
from pathlib import Path

PACKAGE = Path(__file__).resolve().parents[2] / "lfusd"


def _function(path: Path, name: str) -> ast.FunctionDef:
    tree = ast.parse(path.read_text())
    return next(n for n in tree.body if isinstance(n, ast.FunctionDef) and n.name == name)


def _called(fn: ast.FunctionDef) -> list[str]:
    """The names called in ``fn`` (``f(...)`` and ``x.f(...)``), in source order."""
    calls = [n for n in ast.walk(fn) if isinstance(n, ast.Call)]
    calls.sort(key=lambda n: (n.lineno, n.col_offset))
    return [c.func.id if isinstance(c.func, ast.Name) else c.func.attr for c in calls if isinstance(c.func, (ast.Name, ast.Attribute))]


def test_render_video_runs_the_job_steps_in_order_from_one_function():
    fn = _function(PACKAGE / "render" / "job.py", "render_video")
    called = _called(fn)
    steps = ["_plan_job", "_open_folder", "_motion_scheduler", "run", "_derive_video", "_certify"]
    assert [c for c in called if c in steps] == steps, called


def test_no_closure_is_handed_down_the_render_job():
    """A nested function in the job's entry points would be a callback the layers below climb back into."""
    for name in ("render", "render_video"):
        fn = _function(PACKAGE / "render" / "job.py", name)
        nested = [n.name for n in ast.walk(fn) if isinstance(n, (ast.FunctionDef, ast.Lambda)) and n is not fn and hasattr(n, "name")]
        lambdas = [n for n in ast.walk(fn) if isinstance(n, ast.Lambda)]
        assert not nested and not lambdas, (name, nested)
    tree = ast.parse((PACKAGE / "render" / "job.py").read_text())
    params = {a.arg for n in ast.walk(tree) if isinstance(n, ast.FunctionDef) for a in n.args.args + n.args.kwonlyargs}
    assert not params & {"then", "overlap"}, params & {"then", "overlap"}


def test_the_render_video_command_calls_one_library_function():
    """It parses, calls lfusd.render.job.render_video and prints: verify and its certificate are the library's."""
    fn = _function(PACKAGE / "commands" / "render_video.py", "run")
    imported = {}
    for n in ast.walk(fn):
        if isinstance(n, ast.ImportFrom) and not (n.module or "").startswith(("verify", "args")) and n.level == 2:
            imported.update({a.asname or a.name: n.module for a in n.names})
    assert imported == {"RenderRequest": "render.job", "render_video": "render.job"}, imported
    called = _called(fn)
    assert called.count("render_video") == 1 and "verify" not in called and "record_certificate" not in called, called

"""The documentation site (mkdocs.yml, docs/) and README.md: the site builds with every warning an
error, without pxr, bpy or torch; the command pages hold the parsers' current --help; the tables
copied from code are the code's; README stays a short entry point whose links resolve."""

from __future__ import annotations

import importlib.util
import os
import re
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
DOCS = ROOT / "docs"
README = ROOT / "README.md"


def _docs_help():
    spec = importlib.util.spec_from_file_location("docs_help", ROOT / "scripts" / "docs_help.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


@pytest.mark.timeout(600)  # mkdocs build, up to 300 s on busy cores
def test_site_builds_strict_without_pxr_bpy_or_torch(tmp_path):
    # mkdocs, mkdocs-material and mkdocstrings[python] are in the test extra (scripts/setup.sh
    # installs it): a missing one fails here rather than skipping the build.
    # Packages named pxr, bpy and torch that fail on import, ahead of the real ones on the path:
    # the API reference must come from static analysis of the source alone.
    blocked = tmp_path / "blocked"
    for name in ("pxr", "bpy", "torch"):
        (blocked / name).mkdir(parents=True)
        (blocked / name / "__init__.py").write_text(f"raise ImportError('the docs build imported {name}')\n")
    site = tmp_path / "site"
    env = {**os.environ, "PYTHONPATH": os.pathsep.join([str(blocked), str(ROOT)]), "NO_MKDOCS_2_WARNING": "1"}
    run = subprocess.run([sys.executable, "-m", "mkdocs", "build", "--strict", "-f", str(ROOT / "mkdocs.yml"), "-d", str(site)],
                         cwd=ROOT, env=env, capture_output=True, text=True, timeout=300)
    assert run.returncode == 0, run.stdout + run.stderr
    assert "WARNING" not in run.stderr, run.stderr
    # The API reference holds the documented objects, not empty pages.
    data = (site / "api" / "data" / "index.html").read_text()
    for anchor in ("lfusd.data.dataset.Dataset", "lfusd.data.dataset.Dataset.read", "lfusd.exports.export"):
        assert f'id="{anchor}"' in data, anchor
    assert 'id="lfusd.render.worker"' in (site / "api" / "render" / "index.html").read_text()
    assert (site / "CONVENTIONS" / "index.html").is_file() and (site / "contact_sheet.png").is_file()


def test_every_command_has_its_current_help_on_a_command_page():
    dh = _docs_help()
    parsers, blocks = dh.commands(), dh.documented()
    missing = sorted(set(parsers) - set(blocks))
    assert not missing, (f"no help block for {missing} in docs/commands/: add '<!-- BEGIN help: COMMAND -->' and "
                         "'<!-- END help -->' to its page, then run `python scripts/docs_help.py`")
    assert not set(blocks) - set(parsers), f"help blocks of commands that do not exist: {sorted(set(blocks) - set(parsers))}"
    stale = [cmd for cmd, (page, body) in blocks.items() if body != dh.block(dh.help_text(parsers[cmd]))]
    assert not stale, f"--help changed for {stale}: run `python scripts/docs_help.py`"
    for cmd, (page, _) in blocks.items():
        assert page.parent == DOCS / "commands", f"{cmd}: help blocks belong on the command pages, not {page}"


def test_help_is_formatted_at_a_fixed_width_whatever_the_terminal(monkeypatch):
    dh = _docs_help()
    parser = dh.commands()["lfusd render-video"]
    monkeypatch.setenv("COLUMNS", "40")
    narrow = dh.help_text(parser)
    monkeypatch.setenv("COLUMNS", "200")
    assert dh.help_text(parser) == narrow and os.environ["COLUMNS"] == "200"
    assert max(map(len, narrow.splitlines())) <= dh.WIDTH


def test_the_joint_alias_table_in_conventions_is_the_code_s():
    from lfusd.author.skeletons import ALIASES

    text = (DOCS / "CONVENTIONS.md").read_text()
    section = text[text.index("## Characters"):text.index("\n## ", text.index("## Characters") + 1)]
    rows = re.findall(r"^\| (\w+) \| (.+) \|$", section, re.M)
    table = {role: tuple(re.findall(r"`([^`]+)`", names)) for role, names in rows if role != "role"}
    assert table == ALIASES


def test_readme_is_a_short_entry_point_whose_links_resolve():
    text = README.read_text()
    assert len(text.splitlines()) < 150
    assert "make demo   #" in text and "make test   #" in text
    assert "docs/contact_sheet.png" in text
    links = re.findall(r"\]\(([^)]+)\)", text)
    local = [link.split("#")[0] for link in links if not re.match(r"[a-z]+://", link)]
    assert len(local) >= 10, "README links the docs pages"
    assert [link for link in local if not (ROOT / link).exists()] == []
    # every page of the site is reachable from the README, directly or through the site's index
    assert "docs/index.md" in local or all(f"docs/{p.relative_to(DOCS)}" in local for p in DOCS.glob("*.md"))

"""Importing lfusd and its reader stays light: no USD, no Blender, no PyTorch."""

import subprocess
import sys

import pytest

HEAVY = ("pxr", "bpy", "torch")


@pytest.mark.parametrize(
    "code",
    [
        "import lfusd; lfusd.Dataset",
        "from lfusd import Dataset",
        "import lfusd.keys, lfusd.layout, lfusd.camera, lfusd.data.dataset, lfusd.data.passes",
    ],
)
def test_reader_imports_neither_pxr_bpy_nor_torch(code):
    check = f"{code}\nimport sys\nprint(','.join(m for m in {HEAVY!r} if m in sys.modules))"
    out = subprocess.run([sys.executable, "-c", check], capture_output=True, text=True, check=True).stdout.strip()
    assert out == "", f"{code!r} imported {out}"


def test_the_check_sees_a_heavy_import():
    """The probe itself works: importing the renderer's job module does load pxr."""
    check = "import lfusd.render.job\nimport sys\nprint('pxr' in sys.modules)"
    out = subprocess.run([sys.executable, "-c", check], capture_output=True, text=True, check=True).stdout.strip()
    assert out == "True"

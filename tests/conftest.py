import sys
from pathlib import Path

import pytest

sys.path.insert(0, str(Path(__file__).parent))  # tests/analytic.py, tests/scenes.py


@pytest.fixture(scope="session")
def box_dataset(tmp_path_factory):
    """A stage with two rigs (plane 3x3 at 64x48, sphere 2x3 at 40x40), rendered once."""
    from support.scenes import PLANE_RIG, SPHERE_RIG, write_box_stage

    from lfusd.render.job import RenderRequest, render

    root = tmp_path_factory.mktemp("boxes")
    stage = root / "boxes.usda"
    write_box_stage(stage, [PLANE_RIG, SPHERE_RIG])
    out = root / "out"
    render(RenderRequest(stage=stage, out=out, rig="all", samples=4, device="cpu", quiet=True))
    return stage, out

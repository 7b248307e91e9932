import sys
from pathlib import Path

import pytest

sys.path.insert(0, str(Path(__file__).parent))  # tests/support/...

# The `blender` marker and the guard that keeps `make test-fast` free of Blender (its hooks, by import).
from support.markers import (  # noqa: E402, F401
    pytest_collection_modifyitems,
    pytest_configure,
    pytest_runtest_call,
    pytest_runtest_setup,
    pytest_runtest_teardown,
    pytest_unconfigure,
    pytest_xdist_auto_num_workers,
)


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

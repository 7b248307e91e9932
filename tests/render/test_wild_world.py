"""Stages in other axes and units (Y-up centimetres, Y-up metres, Z-up inches) render in lfusd's world.

Each stage holds the same physical scene (tests/support/world_stages.py): a ground quad, a box
translating over 3 frames, a distant light and a 2x2 rig added with `add_rig`. After
render-video + verify (every key compared), the dataset is checked in closed form: the position
and normal at a pixel on the box's top face are the ray's hit on that face in the world the
convention defines (R * metersPerUnit * stage point), and the forward flow there is the
projection of the box's known motion.
"""

from __future__ import annotations

import numpy as np
import pytest

from tests.support.wild import render_and_verify
from tests.support.world_stages import BOX_EDGE, BOX_STEP, box_centre, to_stage, to_world, world_rig, write_world_stage

pytestmark = pytest.mark.render

STAGES = [("Y", 0.01), ("Y", 1.0), ("Z", 0.0254)]


def _project(K, c2w, p):
    q = np.linalg.inv(c2w) @ np.append(p, 1.0)
    uvw = K @ q[:3]
    return uvw[:2] / uvw[2]


@pytest.mark.parametrize("up,mpu", STAGES, ids=["yup-cm", "yup-m", "zup-inch"])
def test_stage_in_other_axes_and_units_renders_in_lfusds_world(tmp_path, up, mpu):
    stage = tmp_path / "s.usda"
    write_world_stage(stage, up, mpu, world_rig(up))
    ds, _ = render_and_verify(stage, tmp_path / "out")

    world = ds.manifest["world"]
    assert world["up_axis"] == up and world["meters_per_unit"] == pytest.approx(mpu)
    assert np.array(world["stage_to_world"]) @ np.append(to_stage([1.0, 2.0, 3.0], up, mpu), 1) == pytest.approx([1, 2, 3, 1])

    frame, view = 1, (0, 0)
    K, c2w = ds.intrinsics(view), ds.cam_to_world(frame, view)
    # The top face's centre, a stage point mapped by hand, projects inside the image ...
    top_stage = to_stage(box_centre(frame) + [0, 0, BOX_EDGE / 2], up, mpu)
    top = to_world(top_stage, up, mpu)
    u, v = _project(K, c2w, top)
    i, j = int(round(v)), int(round(u))
    assert 2 <= i < ds.resolution[1] - 2 and 2 <= j < ds.resolution[0] - 2
    # ... and the pixel centre nearest it sees the face: the ray's hit on the plane z = top.
    ray = c2w[:3, :3] @ np.linalg.inv(K) @ [j, i, 1.0]
    hit = c2w[:3, 3] + ray * (top[2] - c2w[2, 3]) / ray[2]
    assert np.abs(hit - top)[:2].max() < BOX_EDGE / 4  # well inside the face
    position = ds.read(frame, view, "position")[i, j]
    assert position == pytest.approx(hit, abs=2e-4)
    assert ds.read(frame, view, "normal")[i, j] == pytest.approx([0, 0, 1], abs=1e-3)
    # Forward flow: the hit point moves with the box (pure translation) to hit + BOX_STEP at t+1.
    u2, v2 = _project(K, ds.cam_to_world(frame + 1, view), hit + BOX_STEP)
    flow = ds.read(frame, view, "flow_fwd")[i, j]
    assert flow == pytest.approx([u2 - j, v2 - i], abs=0.05)
    assert np.hypot(*flow) > 0.5  # the motion is visible, so the check can fail
    assert ds.read(frame, view, "scene_flow")[i, j] == pytest.approx(BOX_STEP, abs=1e-3)

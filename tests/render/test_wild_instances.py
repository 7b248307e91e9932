"""Real-world-shaped stages with instancing, rendered and verified: (a) scenegraph instances (one
moving, each holding a PointInstancer), (b) nested PointInstancers with time-sampled positions.
Beyond `render_and_verify`, closed-form checks: each instance's own id at its projected top centre,
Dataset.objects against the authored placements, and the moving instance's flow against the
projection of its known motion."""

import numpy as np
import pytest

from lfusd.camera import Camera, RigSpec, project, ray_directions
from tests.support.instances import CROWN, PINE, PINES, TREES, expected_objects, write_instances_stage
from tests.support.wild import render_and_verify

pytestmark = pytest.mark.render

CASES = {
    # name: (stage options, rig looking down on it, {object path: top centre(frame)}, moving object)
    "scenegraph": (
        dict(points=False),
        RigSpec(name="main", rows=2, cols=2, width=32, height=32, baseline=0.05, at=(0.0, -1.8, 5.5), look_at=(0.0, -0.2, 0.4)),
        {p: (lambda f, pos=pos: pos(f) + np.array([0, 0, CROWN[0][2] + CROWN[1] / 2])) for p, pos in TREES.items()},
        "/World/Forest/Tree_1",
    ),
    "points": (
        dict(scenegraph=False),
        RigSpec(name="main", rows=2, cols=2, width=32, height=32, baseline=0.05, at=(0.1, 1.8, 4.5), look_at=(0.1, 3.0, 0.3)),
        {f"/World/Forest/Trees[{i}]": (lambda f, pos=pos: pos(f) + np.array([0, 0, PINE[0][2] + PINE[1] / 2])) for i, pos in enumerate(PINES)},
        "/World/Forest/Trees[2]",
    ),
}


@pytest.mark.parametrize("case", sorted(CASES))
def test_instances_render_as_objects_of_their_own(tmp_path, case):
    options, rig, tops, mover = CASES[case]
    stage = tmp_path / "stage.usda"
    write_instances_stage(stage, rig, **options)
    ds, _ = render_and_verify(stage, tmp_path / "out")
    expected = expected_objects(**options)
    objects = {o.prim_path: o for o in ds.objects.values()}
    assert set(objects) == set(expected)
    for path, (label, t) in expected.items():
        assert objects[path].label == label
        for f in ds.frames:
            want = np.eye(4)
            want[:3, 3] = t(f)
            np.testing.assert_allclose(objects[path].poses[f], want, atol=1e-6, err_msg=f"{path} frame {f}")
    for view in ds.views:
        cam = Camera(ds.intrinsics(view), ds.cam_to_world(1, view))
        inst = ds.read(1, view, "instance")
        seen = {}
        for path, top in tops.items():
            u, v, _ = project(top(1)[None], cam)
            seen[path] = int(inst[int(round(v[0])), int(round(u[0]))])
            assert seen[path] == objects[path].instance_id, f"{path} in view {view}: id {seen[path]}"
        assert len(set(seen.values())) == len(seen)
        # Forward flow of the mover's top face at the pixel nearest its top centre: that face point
        # moves with the instance's known translation.
        u, v, _ = project(tops[mover](1)[None], cam)
        j, i = int(round(u[0])), int(round(v[0]))
        d = ray_directions(np.array([float(j)]), np.array([float(i)]), cam)[0]
        origin = ds.cam_to_world(1, view)[:3, 3]
        X = origin + (tops[mover](1)[2] - origin[2]) / d[2] * d
        X1 = X + expected[mover][1](2) - expected[mover][1](1)
        u1, v1, _ = project(ds.cam_to_world(2, view)[:3, 3] * 0 + X1[None], Camera(ds.intrinsics(view), ds.cam_to_world(2, view)))
        flow = ds.read(1, view, "flow_fwd")[i, j]
        np.testing.assert_allclose(flow, [u1[0] - j, v1[0] - i], atol=0.05)
        assert np.linalg.norm(flow) > 0.3  # the motion is visible

"""Trees' leaves are real geometry (issue 25 item 4): a generated tree's leaves are rendered, seen
in the ground truth where closed-form projections put them, and pass `lfusd verify`.

Marked ``render``: one rig of 2x2 views at 48x48, 2 frames, 1 sample (about 15 s on 2 CPU cores).
"""

from __future__ import annotations

import logging

import numpy as np
import pytest
from support.wild import render_and_verify

from lfusd.camera import RigSpec

pytestmark = pytest.mark.render
log = logging.getLogger(__name__)


def test_leaves_are_rendered_seen_by_the_ground_truth_and_verified(tmp_path):
    from lfusd.author.geometry import StageGeometry
    from lfusd.author.labels import object_table
    from lfusd.author.rigs import add_rig
    from lfusd.author.scenes import generate

    path = tmp_path / "street.usda"
    stage = generate("street", path, 3, frames=2, rigs=0)
    geo = StageGeometry(stage)
    tree = next(o for o in object_table(stage)[0] if o.label == "tree" and stage.GetPrimAtPath(f"{o.prim_path}/leaves"))
    crown = geo.mesh(stage.GetPrimAtPath(f"{tree.prim_path}/crown"), 1).vertices
    # 4 m from the crown's middle, from the road's side, looking at it: crown and leaves against the sky
    centre = (crown.min(0) + crown.max(0)) / 2
    at = centre + np.array([0.0, -4.0 if centre[1] > 0 else 4.0, -0.5])
    add_rig(stage, RigSpec(name="leaves", rows=2, cols=2, width=48, height=48, baseline=0.05,
                           at=tuple(float(v) for v in at), look_at=tuple(float(v) for v in centre)))
    stage.GetRootLayer().Save()
    ds, _ = render_and_verify(path, tmp_path / "out", "--frames", "1-2")
    (tid,) = [i for i, o in ds.objects.items() if o.prim_path == tree.prim_path]
    view = (0, 0)
    depth, instance = ds.read(1, view, "depth"), ds.read(1, view, "instance")
    assert (instance == tid).mean() > 0.3  # the tree fills the view
    # closed-form visibility: rays through the pixel centres cast (Open3D) against the leaves and against
    # every other surface of the stage; where a leaf is hit first, the ground truth holds that leaf
    import open3d as o3d

    def first_hit(meshes):
        scene = o3d.t.geometry.RaycastingScene()
        for m in meshes:
            scene.add_triangles(m.vertices.astype(np.float32), m.triangles.astype(np.uint32))
        return scene.cast_rays(o3d.core.Tensor(rays))["t_hit"].numpy()

    K, c2w = ds.intrinsics(view), ds.cam_to_world(1, view)
    jj, ii = np.meshgrid(np.arange(48.0), np.arange(48.0))
    cam = np.stack([(jj - K[0, 2]) / K[0, 0], (ii - K[1, 2]) / K[1, 1], np.ones_like(jj)], axis=-1).reshape(-1, 3)
    rays = np.c_[np.broadcast_to(c2w[:3, 3], cam.shape), cam @ c2w[:3, :3].T].astype(np.float32)  # t = planar depth
    others = [geo.mesh(p, 1) for o in object_table(stage)[0] for p in geo.parts_of(o.prim_path)
              if str(getattr(p, "GetPath", lambda: "")()) != f"{tree.prim_path}/leaves"]
    t_leaf, t_rest = first_hit([geo.mesh(stage.GetPrimAtPath(f"{tree.prim_path}/leaves"), 1)]), first_hit(others)
    leaf = t_leaf < t_rest
    match = np.isclose(depth.ravel()[leaf], t_leaf[leaf], rtol=1e-3) & (instance.ravel()[leaf] == tid)
    log.info("%d of %d pixels see a leaf first (of %d surfaces cast); the ground truth agrees on %.1f%% of them",
             leaf.sum(), leaf.size, len(others) + 1, 100 * match.mean())
    assert leaf.sum() >= 20 and match.mean() >= 0.98, (leaf.sum(), match.mean())

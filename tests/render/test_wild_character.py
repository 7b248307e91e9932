"""A glTF-style character (Y-up, rotateX -90 and scale 0.01 above its SkelRoot, Mixamo joint names)
placed with `lfusd animate add-person --character`, rendered and verified: every motion key is
compared, and the character's instance id lies where its head projects."""

from __future__ import annotations

import numpy as np
import pytest
from pxr import Usd, UsdGeom

from lfusd.author.geometry import StageGeometry
from lfusd.author.labels import set_class_label
from lfusd.author.rigs import add_rig
from lfusd.author.stage import new_stage
from lfusd.camera import RigSpec
from lfusd.cli import main
from support.characters import box_mesh, gltf_mixamo
from support.wild import render_and_verify

pytestmark = pytest.mark.render

FRAMES = (8, 9, 10)
PERSON = "/World/People/Person_00"
# Looking almost straight down on where the person is at frames 8-10 (about 0.1 m along its path
# from x = -1): the ground is nearly fronto-parallel, so verification finds interior ground pixels
# at 32x32, and the head, on top, is what the camera sees of the person at its projected position.
RIG = RigSpec(name="main", rows=2, cols=2, width=32, height=32, baseline=0.05, at=(-0.9, -0.3, 4.0),
              look_at=(-0.9, 0.0, 0.9))


def test_gltf_character_renders_and_verifies(tmp_path):
    char = tmp_path / "character.usda"
    gltf_mixamo(char)
    path = tmp_path / "stage.usda"
    stage = new_stage(path, 1, 12)
    set_class_label(UsdGeom.Xform.Define(stage, "/World/Ground").GetPrim(), "ground")
    ground = UsdGeom.Mesh.Define(stage, "/World/Ground/Mesh")
    ground.CreatePointsAttr([(-10, -10, 0), (10, -10, 0), (10, 10, 0), (-10, 10, 0)])
    ground.CreateFaceVertexCountsAttr([4])
    ground.CreateFaceVertexIndicesAttr([0, 1, 2, 3])
    ground.CreateSubdivisionSchemeAttr("none")
    add_rig(stage, RIG)
    stage.GetRootLayer().Save()
    assert main(["animate", "add-person", str(path), "--path", "-1,0", "3,0", "--character", str(char)]) == 0

    ds, _ = render_and_verify(path, tmp_path / "out", "--frames", f"{FRAMES[0]}-{FRAMES[-1]}")

    ids = [i for i, o in ds.objects.items() if o.prim_path == PERSON]
    assert len(ids) == 1
    stage = Usd.Stage.Open(str(path))
    head = np.array(box_mesh()[3]) == "head"
    body = stage.GetPrimAtPath(f"{PERSON}/Character/Body")
    for frame in FRAMES:
        centre = StageGeometry(stage).mesh(body, float(frame)).vertices[head].mean(axis=0)
        for view in ds.views:
            cam = np.linalg.inv(ds.cam_to_world(frame, view)) @ [*centre, 1.0]
            u, v, w = ds.intrinsics(view) @ cam[:3]
            col, row = int(round(u / w)), int(round(v / w))
            assert 0 <= row < RIG.height and 0 <= col < RIG.width, (frame, view, u / w, v / w)
            assert ds.read(frame, view, "instance")[row, col] == ids[0], (frame, view, row, col)

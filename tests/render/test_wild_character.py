"""A glTF-style character (Y-up, rotateX -90 and scale 0.01 above its SkelRoot, Mixamo joint names)
placed with `lfusd animate add-person --character`, rendered and verified: every motion key is
compared, and the character's instance id lies where its head projects."""

from __future__ import annotations

import numpy as np
import pytest
from pxr import Usd, UsdGeom, UsdLux

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


def test_gltf_shaped_character_renders_textured_and_verifies(tmp_path):
    """Issue 25: the CesiumMan-shaped character (numbered joints, Y-up centimetres, rotation above
    its SkelRoot, textured through a material outside it) walking on a Y-up centimetre set: a tiny
    render-video and verify pass, and its pixels show its texture's green (the material is in the render)."""
    from lfusd.author.stage import open_stage
    from support.characters import TEXTURE_RGB, gltf_numbered, yup_cm_set
    from support.world_stages import to_stage

    char = tmp_path / "cesium" / "man.usda"
    char.parent.mkdir()
    gltf_numbered(char)
    path = tmp_path / "set.usda"
    yup_cm_set(path)
    # World (-2.5, -1) -> (2.5, -1) given in metres along the stage's X and Z.
    ends = [to_stage([x, -1.0, 0.0], "Y", 1.0) for x in (-2.5, 2.5)]
    assert main(["animate", "add-person", str(path), "--path", *(f"{a[0]:g},{a[2]:g}" for a in ends),
                 "--character", str(char)]) == 0
    stage = open_stage(path)
    # Looking almost straight down on the character about 0.6 m along its path (frames 20-22), as
    # RIG above does, given in metres along the stage's axes.
    at, look = to_stage([-1.85, -1.3, 4.0], "Y", 1.0), to_stage([-1.85, -1.0, 0.9], "Y", 1.0)
    add_rig(stage, RigSpec(name="main", rows=2, cols=2, width=32, height=32, baseline=0.05,
                           at=tuple(float(v) for v in at), look_at=tuple(float(v) for v in look)))
    UsdLux.DistantLight(stage.GetPrimAtPath("/World/Sun")).GetIntensityAttr().Set(4.0)  # the set's sun is dim
    stage.GetRootLayer().Save()
    ds, _ = render_and_verify(path, tmp_path / "out", "--frames", "20-22")
    ids = [i for i, o in ds.objects.items() if o.prim_path == PERSON]
    assert len(ids) == 1
    # The texture is green (sRGB TEXTURE_RGB = 40, 200, 60): lit and shaded, the character's pixels
    # average far greener than red or blue (highlights add grey; the fallback grey, or its displayColor
    # 0.7, 0.5, 0.4, would be no greener than red).
    assert TEXTURE_RGB[1] > 3 * max(TEXTURE_RGB[0], TEXTURE_RGB[2])
    for view in ds.views:
        mask = ds.read(20, view, "instance") == ids[0]
        assert mask.sum() >= 10, view
        r, g, b = ds.read(20, view, "rgb")[mask][..., :3].astype(float).mean(axis=0)
        # the texture's green dominates, clearly above black (the set is lit as its template draws it;
        # its street light gives about 19 of 255 here)
        assert g > 1.5 * max(r, b) and g > 10, (view, r, g, b)


def test_gltf_shaped_character_runs_on_the_street_set_renders_textured_and_verifies(tmp_path):
    """Issue 25: the same character running along the committed street set's pavement (a new layer
    over it, with a rig looking down on the runner about 0.9 m along its path at frames 20-22):
    render-video and verify pass, and its pixels show its texture's green."""
    from pathlib import Path

    from lfusd.author.stage import open_stage
    from support.characters import TEXTURE_RGB, gltf_numbered

    street = Path(__file__).resolve().parents[2] / "stages" / "street_00.usda"
    char = tmp_path / "cesium" / "man.usda"
    char.parent.mkdir()
    gltf_numbered(char)
    path = tmp_path / "shot.usda"
    assert main(["animate", "add-person", str(street), "-o", str(path), "--path", "10,4.6", "17,4.6", "--gait", "run",
                 "--character", str(char)]) == 0
    stage = open_stage(path)
    add_rig(stage, RigSpec(name="main", rows=2, cols=2, width=32, height=32, baseline=0.05, at=(10.9, 4.3, 4.4),
                           look_at=(10.9, 4.6, 1.0)))
    stage.GetRootLayer().Save()
    ds, _ = render_and_verify(path, tmp_path / "out", "--frames", "20-22", rig="main")  # the set has its own rigs too
    ids = [i for i, o in ds.objects.items() if o.prim_path == PERSON]
    assert len(ids) == 1 and TEXTURE_RGB[1] > 3 * max(TEXTURE_RGB[0], TEXTURE_RGB[2])
    for view in ds.views:
        mask = ds.read(20, view, "instance") == ids[0]
        assert mask.sum() >= 10, view
        r, g, b = ds.read(20, view, "rgb")[mask][..., :3].astype(float).mean(axis=0)
        # the texture's green dominates, clearly above black (the set is lit as its template draws it;
        # its street light gives about 19 of 255 here)
        assert g > 1.5 * max(r, b) and g > 10, (view, r, g, b)

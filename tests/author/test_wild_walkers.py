"""Issue 25, acceptance: characters shaped like glTF-converted ones walk and run as shipped.

The character (tests/support/characters.py) has numbered joints as in Khronos' CesiumMan
(``leg_joint_L_1``...), lives in a Y-up centimetre file with a rotateX -90 on the prim above its
SkelRoot, and is textured through a material outside its SkelRoot (a camera and a light sit beside
it). It walks and runs on the committed street set (Z-up metres, on its 0.2 m pavement) and on a
Y-up centimetre set. Checked on pxr-skinned world vertices against the ground under them, found
by ray casts onto the sets' support surfaces: soles within 1 cm of the ground at every frame
(walking: one foot always down; never more than 1 cm into it), no point of a sole sliding 1 cm
along the ground in a step, the texture bound and resolved, nothing else of the file brought along,
and `lfusd check` passing on the stage lfusd wrote.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from pxr import Usd, UsdShade

from lfusd.author.geometry import StageGeometry
from lfusd.author.labels import class_label
from lfusd.cli import main
from support.characters import box_mesh, gltf_numbered, yup_cm_set
from support.skel_measure import sole_heights, sole_slides
from support.world_stages import to_stage

STREET = Path(__file__).resolve().parents[2] / "stages" / "street_00.usda"
PERSON = "/World/People/Person_00"
TOL = 0.01  # metres: the 1 cm


def ground_of(stage: Usd.Stage, classes=("road", "sidewalk", "ground", "grass")):
    """ground(xy): height of the topmost surface labelled one of ``classes`` under each point (Open3D ray casts)."""
    import open3d as o3d

    geo = StageGeometry(stage)
    scene = o3d.t.geometry.RaycastingScene()
    for prim in geo.gprims:
        owner = prim
        while owner and not class_label(owner):
            owner = owner.GetParent()
        if owner and class_label(owner) in classes:
            m = geo.mesh(prim, 1.0)
            scene.add_triangles(m.vertices.astype(np.float32), m.triangles.astype(np.uint32))

    def ground(xy):
        rays = np.zeros((len(xy), 6), np.float32)
        rays[:, :2], rays[:, 2], rays[:, 5] = xy, 100.0, -1.0
        t = scene.cast_rays(o3d.core.Tensor(rays))["t_hit"].numpy()
        assert np.all(np.isfinite(t)), "a foot left the support surfaces"
        return 100.0 - t

    return ground


def place(tmp_path, where: str, gait: str):
    """Add the character with the CLI; returns (the stage lfusd wrote, the path it walks in world xy)."""
    char = tmp_path / "cesium" / "man.usda"  # in its own folder, as downloaded: the stage references it there
    char.parent.mkdir()
    gltf_numbered(char)
    if where == "street":
        out = tmp_path / "shot.usda"  # a layer over the committed set, which stays unchanged
        args = [str(STREET), "-o", str(out), "--path", "10,4.6", "17,4.6"]
        world = np.array([[10.0, 4.6], [17.0, 4.6]])
    else:
        out = tmp_path / "set.usda"
        yup_cm_set(out)
        world = np.array([[-2.5, -1.0], [2.5, -1.0]])
        ax = [to_stage([x, y, 0.0], "Y", 1.0) for x, y in world]  # metres along the stage's X and Z
        args = [str(out), "--path", *(f"{a[0]:g},{a[2]:g}" for a in ax)]
    assert main(["animate", "add-person", *args, "--character", str(char), "--gait", gait]) == 0
    return out, world


@pytest.mark.slow
@pytest.mark.parametrize("where", ["street", "yup-cm"])
@pytest.mark.parametrize("gait", ["walk", "run"])
def test_gltf_shaped_character_walks_and_runs_with_its_soles_on_the_ground(tmp_path, capsys, where, gait):
    path, world = place(tmp_path, where, gait)
    stage = Usd.Stage.Open(str(path))
    first, last = int(stage.GetStartTimeCode()), int(stage.GetEndTimeCode())
    body = stage.GetPrimAtPath(f"{PERSON}/Character/Body")
    assert body and class_label(stage.GetPrimAtPath(PERSON)) == "person"
    geo = StageGeometry(stage)
    verts = np.array([geo.mesh(body, float(f)).vertices for f in range(first, last + 1)])
    keys = np.array(box_mesh()[3])
    feet = [(keys == f"{s}_ankle") | (keys == f"{s}_toe") for s in "lr"]
    ground = ground_of(stage)

    h = sole_heights(verts, feet, ground)
    assert h.min() > -TOL, f"a sole sinks {-h.min():.3f} m into the ground"
    assert np.all(np.abs(h[0]) < TOL), "standing at the start: both soles on the ground"
    if gait == "walk":
        assert np.all(h.min(axis=1) < TOL), f"no sole on the ground at frames {np.nonzero(h.min(axis=1) >= TOL)[0] + first}"
    else:  # a run has flight phases, and each foot lands again and again
        for k in range(2):
            down = h[:, k] < TOL
            assert np.count_nonzero(down[1:] & ~down[:-1]) >= 3
        assert h.max() > 0.05  # it does leave the ground
    assert sole_slides(verts, feet, ground).max() < TOL

    # It went along its path: the body's centre moved from the first point towards the last.
    centre = verts.mean(axis=1)[:, :2]
    direction = (world[1] - world[0]) / np.linalg.norm(world[1] - world[0])
    assert np.linalg.norm(centre[0] - world[0]) < 0.2
    assert (centre[-1] - world[0]) @ direction > 3.0
    assert np.abs((centre - world[0]) @ [-direction[1], direction[0]]).max() < 0.1

    # Its textured material came along (the file's camera and light did not), and resolves.
    mat, _ = UsdShade.MaterialBindingAPI(body).ComputeBoundMaterial()
    assert mat and mat.GetPath().HasPrefix(PERSON)
    files = [a.Get() for p in Usd.PrimRange(mat.GetPrim()) for a in p.GetAttributes() if a.GetName() == "inputs:file"]
    assert files and all(Path(f.resolvedPath).is_file() for f in files)
    assert not stage.GetPrimAtPath(f"{PERSON}/Camera").IsActive() and not stage.GetPrimAtPath(f"{PERSON}/Light").IsActive()

    capsys.readouterr()
    assert main(["check", str(path)]) == 0, capsys.readouterr().out


def test_anonymous_joint_names_still_swing_the_arms(tmp_path):
    """Arms are found by the skeleton's shape, not its names: a character whose joints are called
    joint_0, joint_1, ... (no side or limb words at all), Y-up centimetres under a rotateX -90,
    walks on the Y-up centimetre set with its hands swinging in opposition, forward and back along
    its path (measured on the skinned hand vertices, relative to the hips)."""
    from lfusd.author.people import add_person
    from support.characters import scaled, write_character

    char = tmp_path / "anon" / "man.usda"
    char.parent.mkdir()
    write_character(char, "cesium", up="Y", meters_per_unit=0.01, content=scaled(100.0, 180.0), above=[("rotateX", -90.0)],
                    textured=True, seed=5)
    path = tmp_path / "set.usda"
    yup_cm_set(path)
    stage = Usd.Stage.Open(str(path))
    route = [to_stage([x, -1.0, 0.0], "Y", 1.0) for x in (-2.5, 2.5)]
    add_person(stage, [(a[0], a[2]) for a in route], gait="walk", character=char, check=False)
    body = stage.GetPrimAtPath(f"{PERSON}/Character/Body")
    geo = StageGeometry(stage)
    verts = np.array([geo.mesh(body, float(f)).vertices for f in range(24, 61)])  # at speed
    keys = np.array(box_mesh()[3])
    hips = verts[:, keys == "pelvis"].mean(axis=1)
    ahead = [(verts[:, keys == f"{s}_wrist"].mean(axis=1) - hips)[:, 0] for s in "lr"]  # the path runs along world +x
    for a in ahead:
        assert np.ptp(a) > 0.15, f"a hand swings only {np.ptp(a):.3f} m"
    assert np.corrcoef(*ahead)[0, 1] < -0.8  # left forward while right back

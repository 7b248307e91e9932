"""StageGeometry against closed-form motion: a translating/rotating cube and hand-computed LBS."""

import math

import numpy as np
import pytest
from pxr import Gf, Sdf, UsdGeom

from lfusd.errors import LfusdError
from lfusd.author.geometry import StageGeometry, triangulate
from lfusd.author.stage import new_stage
from support.skinned import ANGLES, hom, rot_x, rot_z, skinned_stage


def cube_stage(mpu=1.0, size=2.0):
    stage = new_stage(None, 1, 3)
    UsdGeom.SetStageMetersPerUnit(stage, mpu)
    cube = UsdGeom.Cube.Define(stage, "/World/Box")
    cube.CreateSizeAttr(size)
    tr, rz = cube.AddTranslateOp(), cube.AddRotateZOp()
    for f in (1, 2, 3):
        tr.Set(Gf.Vec3d(0.5 * f, -0.25 * f, 1.0), f)
        rz.Set(30.0 * f, f)  # degrees
    return stage


def _corners(half):
    return np.array([[x, y, z] for x in (-1, 1) for y in (-1, 1) for z in (-1, 1)], float) * half


def test_cube_translating_and_rotating_matches_closed_form():
    geo = StageGeometry(cube_stage())
    for f in (1, 2, 3):
        (m,) = geo.meshes(f)
        # USD op order translate then rotateZ: p_world = T (Rz p).
        expect = _corners(1.0) @ rot_z(math.radians(30.0 * f)).T + np.array([0.5 * f, -0.25 * f, 1.0])
        np.testing.assert_allclose(m.vertices, expect, atol=1e-12)
        assert m.triangles.shape == (12, 3)


def test_cube_mesh_is_closed_with_right_area_and_meters_per_unit():
    geo = StageGeometry(cube_stage(mpu=0.01, size=200.0))  # 200 cm cube = 2 m
    (m,) = geo.meshes(1)
    v, t = m.vertices, m.triangles
    area = 0.5 * np.linalg.norm(np.cross(v[t[:, 1]] - v[t[:, 0]], v[t[:, 2]] - v[t[:, 0]]), axis=1).sum()
    assert area == pytest.approx(6 * 2.0 * 2.0)
    np.testing.assert_allclose(v.mean(0), [0.005, -0.0025, 0.01], atol=1e-12)  # translate (0.5,-0.25,1) cm
    edges = np.sort(np.concatenate([t[:, [0, 1]], t[:, [1, 2]], t[:, [2, 0]]]), axis=1)
    _, counts = np.unique(edges, axis=0, return_counts=True)
    assert (counts == 2).all()  # every edge shared by exactly two triangles: a closed surface


def test_triangulate_fans_polygons_in_face_order():
    tris = triangulate(np.array([3, 4, 5]), np.arange(12))
    np.testing.assert_array_equal(tris, [[0, 1, 2], [3, 4, 5], [3, 5, 6], [7, 8, 9], [7, 9, 10], [7, 10, 11]])




def test_skinned_two_joint_limb_matches_hand_computed_lbs():
    stage, pts, weights = skinned_stage()
    geo = StageGeometry(stage)
    assert geo.is_skinned("/World/Arm/Limb")
    G = hom(t=(0.05, 0, 0))
    bind_inv = [np.eye(4), np.linalg.inv(hom(t=(0, 0, 1)))]
    root_world = hom(t=(1.0, 2.0, 0.0))
    ph = np.c_[pts, np.ones(len(pts))] @ G.T
    for f, (a, b) in ANGLES.items():
        W_root = hom(rot_z(a))
        W_elbow = W_root @ hom(rot_x(b), (0, 0, 1))  # child local = translate then rotate about the elbow
        skel_pts = sum(weights[:, [i]] * (ph @ (W @ Binv).T) for i, (W, Binv) in enumerate(zip((W_root, W_elbow), bind_inv)))
        expect = (skel_pts @ root_world.T)[:, :3]
        (m,) = geo.meshes(f)
        np.testing.assert_allclose(m.vertices, expect, atol=2e-6)
    # The bend really moves the tip (guards against a test that cannot fail).
    assert np.abs(geo.meshes(3)[0].vertices - geo.meshes(1)[0].vertices).max() > 0.5


def test_implicit_sphere_is_refused_with_a_fix():
    stage = new_stage(None)
    UsdGeom.Sphere.Define(stage, Sdf.Path("/World/Ball"))
    with pytest.raises(LfusdError, match="/World/Ball.*Mesh"):
        StageGeometry(stage).meshes(1)


def test_visibility_follows_authored_invisible_over_time():
    stage = cube_stage()
    vis = UsdGeom.Imageable(stage.GetPrimAtPath("/World/Box")).CreateVisibilityAttr()
    vis.Set(UsdGeom.Tokens.inherited, 1)
    vis.Set(UsdGeom.Tokens.invisible, 2)
    geo = StageGeometry(stage)
    prim = geo.gprims[0]
    assert geo.visible(prim, 1) and not geo.visible(prim, 2)


def test_subdivision_surfaces_are_named_once_by_check(tmp_path, capfd):
    """Meshes authoring a subdivisionScheme other than none are drawn as their cages; `lfusd check`
    says so once, naming the first and counting the rest; unauthored or 'none' meshes are polygons."""
    from pxr import Usd, UsdGeom

    from lfusd.author.geometry import subdivision_surfaces
    from lfusd.cli import main

    path = tmp_path / "s.usda"
    stage = Usd.Stage.CreateNew(str(path))
    UsdGeom.SetStageUpAxis(stage, "Z")
    UsdGeom.SetStageMetersPerUnit(stage, 1.0)
    stage.SetDefaultPrim(UsdGeom.Xform.Define(stage, "/World").GetPrim())
    for name, scheme in (("Cage", "catmullClark"), ("Loop", "loop"), ("Flat", "none"), ("Plain", None)):
        m = UsdGeom.Mesh.Define(stage, f"/World/{name}")
        m.CreatePointsAttr([(0, 0, 0), (1, 0, 0), (0, 1, 0)])
        m.CreateFaceVertexCountsAttr([3])
        m.CreateFaceVertexIndicesAttr([0, 1, 2])
        if scheme:
            m.CreateSubdivisionSchemeAttr(scheme)
    stage.Save()
    assert subdivision_surfaces(list(stage.Traverse())) == ["/World/Cage", "/World/Loop"]
    capfd.readouterr()
    assert main(["check", str(path)]) == 0
    err = capfd.readouterr().err
    assert err.count("renders and verifies its control cage") == 1 and "mesh /World/Cage has subdivisionScheme catmullClark (as do 1 more meshes)" in err

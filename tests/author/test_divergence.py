"""Issue 37 item 5: what Blender renders otherwise than USD defines it is refused before rendering,
by `lfusd check` and by every render (lfusd.author.geometry.check_divergence via check_geometry),
in one line naming the prim: skin weights that do not sum to 1, PointInstancer velocities,
accelerations and angular velocities, sheared point instances and sheared scenegraph instances."""

import math

import pytest
from pxr import Gf, Sdf, UsdGeom, UsdSkel

from lfusd.author.geometry import StageGeometry, check_geometry
from lfusd.author.stage import new_stage
from lfusd.errors import LfusdError
from tests.support.skinned import skinned_stage

QUAD = dict(points=[(-0.5, -0.5, 0), (0.5, -0.5, 0), (0.5, 0.5, 0), (-0.5, 0.5, 0)], counts=[4], indices=[0, 1, 2, 3])


def _mesh(stage, path):
    m = UsdGeom.Mesh.Define(stage, path)
    m.CreatePointsAttr(QUAD["points"])
    m.CreateFaceVertexCountsAttr(QUAD["counts"])
    m.CreateFaceVertexIndicesAttr(QUAD["indices"])
    return m


def _refusal(stage) -> str:
    with pytest.raises(LfusdError) as e:
        check_geometry(StageGeometry(stage))
    line = str(e.value)
    assert "\n" not in line
    return line


def _instancer(stage, scale=(1, 1, 1), proto_rot_z=0.0):
    pi = UsdGeom.PointInstancer.Define(stage, "/World/Scatter")
    proto = _mesh(stage, "/World/Scatter/Protos/Leaf")
    if proto_rot_z:
        proto.AddRotateZOp().Set(proto_rot_z)
    pi.CreatePrototypesRel().SetTargets([proto.GetPath()])
    pi.CreateProtoIndicesAttr([0, 0])
    pi.CreatePositionsAttr([(0, 0, 0), (2, 0, 0)])
    pi.CreateScalesAttr([scale, scale])
    return pi


def test_skin_weights_that_do_not_sum_to_one_are_refused_naming_the_mesh():
    stage, pts, weights = skinned_stage()
    check_geometry(StageGeometry(stage))  # normalised: accepted
    binding = UsdSkel.BindingAPI(stage.GetPrimAtPath("/World/Arm/Limb"))
    binding.GetJointWeightsPrimvar().Set((0.8 * weights).ravel().tolist())
    line = _refusal(stage)
    assert line.startswith("mesh /World/Arm/Limb's skin weights sum to 0.8 at point 0") and "normalise" in line


@pytest.mark.parametrize("attr", ["velocities", "accelerations", "angularVelocities"])
def test_point_instancer_velocities_are_refused_naming_the_instancer(attr):
    stage = new_stage(None, 1, 3)
    pi = _instancer(stage)
    check_geometry(StageGeometry(stage))
    pi.GetPrim().GetAttribute(attr).Set([(0.5, 0, 0), (0.5, 0, 0)])
    line = _refusal(stage)
    assert line.startswith(f"PointInstancer /World/Scatter has {attr}, which Blender ignores"), line


def test_sheared_point_instances_are_refused_and_unsheared_ones_accepted():
    stage = new_stage(None, 1, 3)
    _instancer(stage, scale=(1, 2, 1), proto_rot_z=30.0)  # rotate, then scale along the instance's axes: a shear
    line = _refusal(stage)
    # rows (c, 2s, 0), (-s, 2c, 0) of the 3x3: 90 - angle between them
    c, s = math.cos(math.radians(30)), math.sin(math.radians(30))
    cos = 3 * s * c / math.hypot(c, 2 * s) / math.hypot(s, 2 * c)
    off = 90 - math.degrees(math.acos(cos))
    assert line.startswith("instance /World/Scatter[0] has a sheared transform") and f"{off:.3g} degrees" in line, line
    for scale, rot in (((1, 2, 1), 0.0), ((2, 2, 2), 30.0)):  # non-uniform without rotation, rotation with uniform scale
        stage = new_stage(None, 1, 3)
        _instancer(stage, scale=scale, proto_rot_z=rot)
        check_geometry(StageGeometry(stage))


def test_a_sheared_scenegraph_instance_is_refused_naming_it():
    stage = new_stage(None, 1, 3)
    UsdGeom.Xform.Define(stage, "/Protos/Tree")
    _mesh(stage, "/Protos/Tree/Leaf")
    stage.GetPrimAtPath("/Protos").SetSpecifier(Sdf.SpecifierClass)
    parent = UsdGeom.Xform.Define(stage, "/World/Parent")
    scale = parent.AddScaleOp()
    scale.Set(Gf.Vec3f(1, 2, 1))
    inst = UsdGeom.Xform.Define(stage, "/World/Parent/Tree_1")
    inst.AddRotateZOp().Set(30.0)
    inst.GetPrim().GetReferences().AddInternalReference("/Protos/Tree")
    inst.GetPrim().SetInstanceable(True)
    line = _refusal(stage)
    assert line.startswith("instance /World/Parent/Tree_1/Leaf has a sheared transform"), line
    scale.Set(Gf.Vec3f(2, 2, 2))
    check_geometry(StageGeometry(stage))


def test_lfusd_check_refuses_in_one_line(tmp_path, capsys):
    from lfusd.cli import main

    stage = new_stage(str(tmp_path / "s.usda"), 1, 3)
    _instancer(stage).GetVelocitiesAttr().Set([(0.5, 0, 0), (0.5, 0, 0)])
    stage.Save()
    capsys.readouterr()
    assert main(["check", str(tmp_path / "s.usda"), "--no-usd-validation", "--no-coverage"]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "PointInstancer /World/Scatter has velocities" in err, err

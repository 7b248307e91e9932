"""The procedural human: skeleton, body size and shape, skin weights, label."""

import numpy as np
import pytest
from pxr import Usd, UsdGeom, UsdSkel, Vt

from lfusd.errors import LfusdError
from lfusd.author.human import JOINT_NAMES, HumanSpec, body_mesh, define_human, skin_weights
from lfusd.author.labels import class_label, object_table
from lfusd.author.stage import new_stage


def _stage(spec=HumanSpec()):
    stage = new_stage(None)
    root = define_human(stage, "/World/Person", spec)
    return stage, root


def test_skeleton_has_the_named_joints_in_a_valid_hierarchy():
    stage, _ = _stage()
    skel = UsdSkel.Skeleton(stage.GetPrimAtPath("/World/Person/Skeleton"))
    joints = [str(j) for j in skel.GetJointsAttr().Get()]
    assert len(joints) >= 15
    leaves = {j.split("/")[-1] for j in joints}
    for name in ("pelvis", "spine", "chest", "neck", "head"):
        assert name in leaves
    for side in "lr":
        for name in ("shoulder", "elbow", "wrist", "hip", "knee", "ankle"):
            assert f"{side}_{name}" in leaves
    ok, why = UsdSkel.Topology(Vt.TokenArray(joints)).Validate()
    assert ok, why
    # The knee is below the hip and above the ankle; the head above the neck (bind pose).
    bind = {j.split("/")[-1]: np.array(m)[3, :3] for j, m in zip(joints, skel.GetBindTransformsAttr().Get())}
    assert bind["l_hip"][2] > bind["l_knee"][2] > bind["l_ankle"][2] > 0
    assert bind["head"][2] > bind["neck"][2] > bind["chest"][2] > bind["pelvis"][2]
    assert bind["l_hip"][0] < 0 < bind["r_hip"][0]  # facing +Y, the left side is -X


@pytest.mark.parametrize("height,build", [(1.75, 0.5), (1.5, 0.1), (1.95, 1.0)])
def test_body_has_human_size_and_proportions(height, build):
    pts, counts, idx, parts = body_mesh(HumanSpec(height, build))
    lo, hi = pts.min(axis=0), pts.max(axis=0)
    assert abs(hi[2] - height) < 0.01 * height  # top of the head at the stature
    assert abs(lo[2]) < 1e-9  # soles on the ground plane
    width = hi[0] - lo[0]  # arms hang slightly out in the A-pose: about a quarter of the stature
    assert 0.25 * height < width < 0.42 * height
    depth = hi[1] - lo[1]  # back to toe tips
    assert 0.15 * height < depth < 0.23 * height
    # Every face index is valid and every vertex is used.
    assert idx.max() == len(pts) - 1 and len(np.unique(idx)) == len(pts)
    assert counts.sum() == len(idx)


def test_build_makes_a_heavier_body():
    slim = body_mesh(HumanSpec(1.75, 0.0))[0]
    heavy = body_mesh(HumanSpec(1.75, 1.0))[0]
    waist = lambda p: np.ptp(p[(np.abs(p[:, 2] - 0.62 * 1.75) < 0.02) & (np.abs(p[:, 0]) < 0.2)][:, 0])
    assert waist(heavy) > 1.3 * waist(slim)


def test_body_surface_is_closed_and_outward():
    """Every edge is shared by exactly two faces, and the signed volume is positive (normals out)."""
    pts, counts, idx, _ = body_mesh(HumanSpec())
    starts = np.concatenate([[0], np.cumsum(counts)[:-1]])
    edges = {}
    vol = 0.0
    for s, c in zip(starts, counts):
        f = idx[s : s + c]
        for a, b in zip(f, np.roll(f, -1)):
            edges[(min(a, b), max(a, b))] = edges.get((min(a, b), max(a, b)), 0) + 1
        for k in range(1, c - 1):
            vol += np.dot(pts[f[0]], np.cross(pts[f[k]], pts[f[k + 1]])) / 6.0
    assert set(edges.values()) == {2}
    assert 0.04 < vol < 0.12  # m^3: a 1.75 m, average person is about 0.07 m^3 (the parts overlap)


def test_skin_weights_are_normalised_and_smooth():
    spec = HumanSpec()
    pts, counts, idx, parts = body_mesh(spec)
    ji, jw = skin_weights(spec, pts, parts, counts, idx)
    P_ = {n: i for i, n in enumerate(JOINT_NAMES)}
    assert ji.shape == jw.shape == (len(pts), 4)
    assert np.all(jw >= 0) and np.allclose(jw.sum(axis=1), 1.0)
    dense = np.zeros((len(pts), len(JOINT_NAMES)))
    np.put_along_axis(dense, ji, jw, axis=1)
    # Smooth: neighbouring vertices have similar weights (no hard seams), but for the feet...
    starts = np.concatenate([[0], np.cumsum(counts)[:-1]])
    foot = np.char.endswith(np.array(parts), "_foot")
    diffs = []
    for s, c in zip(starts, counts):
        f = idx[s : s + c]
        if not foot[f].any():
            diffs.append(np.abs(dense[f] - dense[np.roll(f, -1)]).sum(axis=1).max())
    assert max(diffs) < 0.75  # raw inverse-distance weights (no smoothing) reach 1.85 here
    # ...which are two rigid pieces, heel to ball on the ankle and the toes on the toe joint (so
    # that rolling the foot about its ball turns no point of it into the ground).
    for side in "lr":
        on = np.array(parts) == f"{side}_foot"
        assert np.all(jw[on, 0] == 1.0) and set(ji[on, 0]) == {P_[f"{side}_ankle"], P_[f"{side}_toe"]}
    # ...and vertices around the knees and elbows are blended between the two bones.
    P = {n: i for i, n in enumerate(JOINT_NAMES)}
    for a, b in (("l_hip", "l_knee"), ("r_shoulder", "r_elbow")):
        blended = (dense[:, P[a]] > 0.2) & (dense[:, P[b]] > 0.2)
        assert blended.sum() >= 16


def test_rest_pose_skins_to_the_authored_points():
    stage, root = _stage()
    mesh = UsdGeom.Mesh(stage.GetPrimAtPath("/World/Person/Body"))
    cache = UsdSkel.Cache()
    cache.Populate(root, Usd.PrimDefaultPredicate)
    binding = cache.ComputeSkelBindings(root, Usd.PrimDefaultPredicate)[0]
    skin = binding.GetSkinningTargets()[0]
    skel = UsdSkel.Skeleton(stage.GetPrimAtPath("/World/Person/Skeleton"))
    rest_local = skel.GetRestTransformsAttr().Get()
    topo = UsdSkel.Topology(skel.GetJointsAttr().Get())
    world = UsdSkel.ConcatJointTransforms(topo, rest_local)
    inv_bind = [m.GetInverse() for m in skel.GetBindTransformsAttr().Get()]
    xforms = Vt.Matrix4dArray([ib * w for ib, w in zip(inv_bind, world)])
    pts = mesh.GetPointsAttr().Get()
    skinned = Vt.Vec3fArray(pts)
    assert skin.ComputeSkinnedPoints(xforms, skinned)
    assert np.abs(np.array(skinned) - np.array(pts)).max() < 1e-6


def test_human_is_labelled_person_and_is_one_object():
    stage, root = _stage()
    assert class_label(root.GetPrim()) == "person"
    objects, classes = object_table(stage)
    assert [(o.prim_path, o.label) for o in objects] == [("/World/Person", "person")]


@pytest.mark.parametrize("spec", [HumanSpec(0.2, 0.5), HumanSpec(1.7, 1.5)])
def test_bad_spec_is_a_one_line_error(spec):
    with pytest.raises(LfusdError) as e:
        _stage(spec)
    assert "\n" not in str(e.value)


@pytest.mark.parametrize("gait", ["walk", "run"])
def test_thighs_never_pass_through_the_torso(gait):
    """Issue 25: the top of each thigh lies inside the torso's shell at rest; walking or running, no
    vertex of a leg crosses the torso's surface and no vertex of the torso crosses a leg's (one
    inside stays inside, one outside stays outside), so neither passes through the other. Checked
    on pxr-skinned world vertices with Open3D occupancy of each closed shell at each frame."""
    import open3d as o3d

    from lfusd.author.geometry import StageGeometry, triangulate
    from lfusd.author.labels import set_class_label
    from lfusd.author.people import add_person

    stage = new_stage(None, 1, 36)
    ground = UsdGeom.Mesh.Define(stage, "/World/Ground")
    ground.CreatePointsAttr([(-10, -10, 0), (10, -10, 0), (10, 10, 0), (-10, 10, 0)])
    ground.CreateFaceVertexCountsAttr([4])
    ground.CreateFaceVertexIndicesAttr([0, 1, 2, 3])
    set_class_label(ground.GetPrim(), "ground")
    person = add_person(stage, [(-4.0, 0.0), (4.0, 0.0)], gait=gait, check=False)
    pts, counts, idx, parts = body_mesh(HumanSpec())
    parts = np.array(parts)
    starts = np.concatenate([[0], np.cumsum(counts)[:-1]])
    face_part = parts[idx[starts]]

    def shell(part):
        sel = face_part == part
        return triangulate(counts[sel], np.concatenate([idx[s:s + c] for s, c in zip(starts[sel], counts[sel])]))

    pairs = [("torso", "l_leg"), ("torso", "r_leg"), ("l_leg", "torso"), ("r_leg", "torso")]  # (shell, its visitor)

    def inside(v):
        out = []
        for part, visitor in pairs:
            scene = o3d.t.geometry.RaycastingScene()
            scene.add_triangles(v.astype(np.float32), shell(part).astype(np.uint32))
            out.append(scene.compute_occupancy(o3d.core.Tensor(v[parts == visitor].astype(np.float32))).numpy() > 0)
        return out

    rest = inside(pts)
    assert rest[0].sum() >= 8 and rest[1].sum() >= 8  # the thighs' tops are inside the torso
    geo = StageGeometry(stage)
    body = stage.GetPrimAtPath(f"{person.GetPath()}/Body")
    for f in range(1, 37):
        v = geo.mesh(body, float(f)).vertices
        assert len(v) == len(pts)
        for (part, visitor), now, then in zip(pairs, inside(v), rest):
            crossed = np.count_nonzero(now != then)
            assert crossed == 0, f"frame {f}: {crossed} {visitor} vertices crossed the surface of the {part}"

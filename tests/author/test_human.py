"""The procedural human: skeleton, body size and shape, skin weights, label."""

import numpy as np
import pytest
from pxr import Usd, UsdGeom, UsdSkel, Vt

from lfusd.errors import LfusdError
from lfusd.author.human import JOINT_NAMES, RIGID_FOOT, HumanSpec, body_mesh, define_human, rest_positions, skin_weights
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
    ji, jw = skin_weights(spec)
    P_ = {n: i for i, n in enumerate(JOINT_NAMES)}
    assert ji.shape == jw.shape == (len(pts), 4)
    assert np.all(jw >= 0) and np.allclose(jw.sum(axis=1), 1.0)
    dense = np.zeros((len(pts), len(JOINT_NAMES)))
    np.put_along_axis(dense, ji, jw, axis=1)
    # Smooth: neighbouring vertices have similar weights (no hard seams), but for the feet...
    starts = np.concatenate([[0], np.cumsum(counts)[:-1]])
    foot = np.char.endswith(np.array(parts), "_foot") & (pts[:, 2] < RIGID_FOOT * spec.height)
    diffs = []
    for s, c in zip(starts, counts):
        f = idx[s : s + c]
        if not foot[f].any():
            diffs.append(np.abs(dense[f] - dense[np.roll(f, -1)]).sum(axis=1).max())
    assert max(diffs) < 0.5  # raw inverse-distance weights (no smoothing) reach 1.85 here
    # ...which below the ankle are two rigid pieces, heel to ball on the ankle and the toes on the
    # toe joint (so that rolling the foot about its ball turns no point of it into the ground).
    for side in "lr":
        on = (np.array(parts) == f"{side}_foot") & (pts[:, 2] < RIGID_FOOT * spec.height)
        assert on.sum() > 100 and np.all(jw[on, 0] == 1.0) and set(ji[on, 0]) == {P_[f"{side}_ankle"], P_[f"{side}_toe"]}
        sole = on & (pts[:, 2] == 0.0)
        ball = rest_positions(spec)[f"{side}_toe"][1]
        assert np.all(ji[sole & (pts[:, 1] < ball), 0] == P_[f"{side}_ankle"]) and np.all(ji[sole & (pts[:, 1] >= ball), 0] == P_[f"{side}_toe"])
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


def _crossings(v: np.ndarray, quads: np.ndarray) -> int:
    """Edges of the quad mesh ``v``, ``quads`` that pass through one of its triangles farther than
    two quads away (a fold within two quads is a crease, not one part passing through another).
    Open3D lists every triangle each edge's ray meets before the edge's far end."""
    import open3d as o3d

    tris = np.concatenate([quads[:, [0, 1, 2]], quads[:, [0, 2, 3]]])
    e = np.unique(np.sort(np.concatenate([quads[:, [k, (k + 1) % 4]] for k in range(4)]), axis=1), axis=0)
    scene = o3d.t.geometry.RaycastingScene()
    scene.add_triangles(v.astype(np.float32), tris.astype(np.uint32))
    a, d = v[e[:, 0]], v[e[:, 1]] - v[e[:, 0]]
    length = np.linalg.norm(d, axis=1)
    hits = scene.list_intersections(o3d.core.Tensor(np.hstack([a, d / length[:, None]]).astype(np.float32)))
    ray, tri, t = (hits[k].numpy() for k in ("ray_ids", "primitive_ids", "t_hit"))
    inside = (t > 1e-6) & (t < length[ray] - 1e-6)
    ray, tri = ray[inside], tri[inside]
    # Each listed hit confirmed in float64 (Moller-Trumbore): the segment meets the triangle's interior.
    p0, p1, p2 = (v[tris[tri, k]] for k in range(3))
    e1, e2, o, dirn = p1 - p0, p2 - p0, a[ray], d[ray]
    h = np.cross(dirn, e2)
    det = np.einsum("ij,ij->i", e1, h)
    ok = np.abs(det) > 1e-15
    f = 1.0 / np.where(ok, det, 1.0)
    s_ = o - p0
    bu = f * np.einsum("ij,ij->i", s_, h)
    qv = np.cross(s_, e1)
    bv = f * np.einsum("ij,ij->i", dirn, qv)
    tt = f * np.einsum("ij,ij->i", e2, qv)
    ok &= (bu > 0) & (bv > 0) & (bu + bv < 1) & (tt > 1e-9) & (tt < 1 - 1e-9)
    ray, tri = ray[ok], tri[ok]
    one_ring: dict[int, set[int]] = {}
    for q in quads.tolist():
        for v in q:
            one_ring.setdefault(v, set()).update(q)

    def two_rings(v: int) -> set[int]:
        return set().union(*(one_ring[u] for u in one_ring[v]))

    near = np.array([bool(set(tris[k].tolist()) & (two_rings(e[r, 0]) | two_rings(e[r, 1]))) for r, k in zip(ray, tri)], bool)
    return int(np.count_nonzero(~near))


@pytest.mark.parametrize("spec", [HumanSpec(1.75, 0.5), HumanSpec(1.9, 1.0, look=2), HumanSpec(1.55, 0.0, look=3)])
def test_body_surface_does_not_pass_through_itself_at_rest(spec):
    """Issue 25 (thighs through the pelvis): the skin is one surface, and no part of it passes
    through another: the arms hang clear of the torso, the thighs clear of each other."""
    pts, counts, idx, _ = body_mesh(spec)
    assert np.all(counts == 4)
    assert _crossings(pts, idx.reshape(-1, 4)) == 0


def _walking_on_ground(spec, gait):
    """A 36-frame stage with a 20 m ground and one person of ``spec`` walking 8 m along x with ``gait``."""
    from lfusd.author.labels import set_class_label
    from lfusd.author.people import add_person

    stage = new_stage(None, 1, 36)
    ground = UsdGeom.Mesh.Define(stage, "/World/Ground")
    ground.CreatePointsAttr([(-10, -10, 0), (10, -10, 0), (10, 10, 0), (-10, 10, 0)])
    ground.CreateFaceVertexCountsAttr([4])
    ground.CreateFaceVertexIndicesAttr([0, 1, 2, 3])
    set_class_label(ground.GetPrim(), "ground")
    return stage, add_person(stage, [(-4.0, 0.0), (4.0, 0.0)], gait=gait, spec=spec, check=False)


@pytest.mark.parametrize("gait", ["walk", "run"])
def test_skinned_body_never_passes_through_itself(gait):
    """Walking and running, on pxr-skinned world vertices at every frame of a cycle and a half: no
    edge of the skin passes through the skin elsewhere (knees, hips and shoulders bend without
    one part entering another) and the soles stay on or above the ground, within 1 cm."""
    from lfusd.author.geometry import StageGeometry

    for spec in (HumanSpec(1.9, 1.0, look=2), HumanSpec(1.55, 0.0, look=3)):
        stage, person = _walking_on_ground(spec, gait)
        quads = body_mesh(spec)[2].reshape(-1, 4)
        geo = StageGeometry(stage)
        body = stage.GetPrimAtPath(f"{person.GetPath()}/Body")
        for f in range(1, 37):
            v = geo.mesh(body, float(f)).vertices
            assert _crossings(v, quads) == 0, f"frame {f}: the skin passes through itself"
            assert v[:, 2].min() > -0.01, f"frame {f}: a sole sinks {-v[:, 2].min():.3f} m into the ground"


@pytest.mark.parametrize("gait", ["walk", "run"])
def test_hair_stays_on_the_head_and_clothes_are_the_skin(gait):
    """Hair is a closed skinned layer over the scalp: at every frame of a walk and a run its inner
    side is outside the skin and no edge of it passes through the skin, and it stays within its
    thickness (a few centimetres) of the skin. Clothes are face subsets of the skin itself, so they
    cannot leave it or enter it."""
    import open3d as o3d

    from lfusd.author.geometry import StageGeometry, triangulate

    spec = HumanSpec(1.7, 0.6, look=1)  # long hair
    stage, person = _walking_on_ground(spec, gait)
    body = UsdGeom.Mesh(stage.GetPrimAtPath(f"{person.GetPath()}/Body"))
    hair = UsdGeom.Mesh(stage.GetPrimAtPath(f"{person.GetPath()}/Hair"))
    assert hair and UsdSkel.BindingAPI(hair.GetPrim()).GetSkeletonRel().GetTargets()
    assert hair.GetSubdivisionSchemeAttr().Get() == UsdGeom.Tokens.none
    # closed and outward, as verify's ray casts need
    h_counts, h_idx = np.array(hair.GetFaceVertexCountsAttr().Get()), np.array(hair.GetFaceVertexIndicesAttr().Get())
    assert np.all(h_counts == 4)
    quads = h_idx.reshape(-1, 4)
    directed = np.concatenate([quads[:, [k, (k + 1) % 4]] for k in range(4)])
    assert len(np.unique(directed, axis=0)) == len(directed)
    assert {tuple(e) for e in directed.tolist()} == {(b, a) for a, b in directed.tolist()}
    p = np.array(hair.GetPointsAttr().Get(), float)[quads]
    assert sum(np.dot(q[0], np.cross(q[k], q[k + 1])) for q in p for k in (1, 2)) > 0  # outward
    b_tris = triangulate(np.array(body.GetFaceVertexCountsAttr().Get()), np.array(body.GetFaceVertexIndicesAttr().Get()))
    n_hair = len(hair.GetPointsAttr().Get())
    inner = np.arange(n_hair) >= n_hair // 2
    geo = StageGeometry(stage)
    edges = np.unique(np.sort(directed, axis=1), axis=0)
    for f in range(1, 37):
        skin = geo.mesh(body.GetPrim(), float(f)).vertices
        v = geo.mesh(hair.GetPrim(), float(f)).vertices
        scene = o3d.t.geometry.RaycastingScene()
        scene.add_triangles(skin.astype(np.float32), b_tris.astype(np.uint32))
        pts = o3d.core.Tensor(v.astype(np.float32))
        assert scene.compute_occupancy(pts).numpy().sum() == 0, f"frame {f}: hair inside the head"
        dist = scene.compute_distance(pts).numpy()
        assert dist[inner].min() > 0.0003 and dist.max() < 0.05, f"frame {f}: hair {dist.min():.4f}-{dist.max():.4f} m off the skin"
        a, d = v[edges[:, 0]], v[edges[:, 1]] - v[edges[:, 0]]
        length = np.linalg.norm(d, axis=1)
        t = scene.cast_rays(o3d.core.Tensor(np.hstack([a, d / length[:, None]]).astype(np.float32)))["t_hit"].numpy()
        assert np.all(t > length), f"frame {f}: a hair edge passes through the skin"

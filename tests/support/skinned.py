"""Closed-form test geometry: rotations, and a two-joint skinned limb with hand-computable LBS."""

import math

import numpy as np
from pxr import Gf, UsdGeom, UsdSkel

from lfusd.author.stage import new_stage

ANGLES = {1: (0.0, 0.0), 2: (0.3, 0.5), 3: (-0.4, 1.2)}  # (root about z, elbow about x) radians


def rot_z(a):
    c, s = math.cos(a), math.sin(a)
    return np.array([[c, -s, 0], [s, c, 0], [0, 0, 1.0]])


def rot_x(a):
    c, s = math.cos(a), math.sin(a)
    return np.array([[1.0, 0, 0], [0, c, -s], [0, s, c]])


def hom(R=np.eye(3), t=(0, 0, 0)):
    m = np.eye(4)
    m[:3, :3], m[:3, 3] = R, t
    return m


def quat(axis, a):
    s = math.sin(a / 2)
    return Gf.Quatf(math.cos(a / 2), *(s * np.asarray(axis, float)))


def skinned_stage(stage=None, half=0.1):
    """A two-joint limb (root at (1, 2, 0), elbow 1 m up) of square section 2*half, frames 1..3."""
    stage = stage or new_stage(None, 1, 3)
    root = UsdSkel.Root.Define(stage, "/World/Arm")
    root.AddTranslateOp().Set(Gf.Vec3d(1.0, 2.0, 0.0))
    skel = UsdSkel.Skeleton.Define(stage, "/World/Arm/Skel")
    skel.CreateJointsAttr(["root", "root/elbow"])
    skel.CreateBindTransformsAttr([Gf.Matrix4d(1), Gf.Matrix4d(1).SetTranslate(Gf.Vec3d(0, 0, 1))])
    skel.CreateRestTransformsAttr([Gf.Matrix4d(1), Gf.Matrix4d(1).SetTranslate(Gf.Vec3d(0, 0, 1))])
    anim = UsdSkel.Animation.Define(stage, "/World/Arm/Skel/Anim")
    anim.CreateJointsAttr(["root", "root/elbow"])
    anim.CreateTranslationsAttr([Gf.Vec3f(0, 0, 0), Gf.Vec3f(0, 0, 1)])
    anim.CreateScalesAttr([Gf.Vec3h(1, 1, 1), Gf.Vec3h(1, 1, 1)])
    rot = anim.CreateRotationsAttr()
    for f, (a, b) in ANGLES.items():
        rot.Set([quat((0, 0, 1), a), quat((1, 0, 0), b)], f)
    UsdSkel.BindingAPI.Apply(skel.GetPrim()).CreateAnimationSourceRel().SetTargets([anim.GetPath()])
    mesh = UsdGeom.Mesh.Define(stage, "/World/Arm/Limb")
    zs = np.linspace(0.0, 2.0, 5)
    pts = np.array([[x, y, z] for z in zs for (x, y) in ((-half, -half), (half, -half), (half, half), (-half, half))])
    mesh.CreatePointsAttr([Gf.Vec3f(*p) for p in pts])
    faces = [[4 * i + k, 4 * i + (k + 1) % 4, 4 * (i + 1) + (k + 1) % 4, 4 * (i + 1) + k] for i in range(4) for k in range(4)]
    mesh.CreateFaceVertexCountsAttr([4] * len(faces))
    mesh.CreateFaceVertexIndicesAttr([i for f in faces for i in f])
    # Weights blend from the root (bottom) to the elbow (top); two influences per point.
    w_elbow = np.clip((pts[:, 2] - 0.5) / 1.0, 0.0, 1.0)
    weights = np.stack([1.0 - w_elbow, w_elbow], axis=1)
    binding = UsdSkel.BindingAPI.Apply(mesh.GetPrim())
    binding.CreateSkeletonRel().SetTargets([skel.GetPath()])
    binding.CreateJointIndicesPrimvar(False, 2).Set([0, 1] * len(pts))
    binding.CreateJointWeightsPrimvar(False, 2).Set(weights.ravel().tolist())
    geom_bind = Gf.Matrix4d(1).SetTranslate(Gf.Vec3d(0.05, 0.0, 0.0))
    binding.CreateGeomBindTransformAttr(geom_bind)
    # The mesh's own transform is ignored by UsdSkel skinning; author one to prove it.
    mesh.AddTranslateOp().Set(Gf.Vec3d(100.0, 0, 0))
    return stage, pts, weights

"""UsdSkel characters shaped like converter output (glTF/FBX, Mixamo, SMPL), written with plain pxr.

A character is a box per bone, each box rigidly skinned to its joint, on an 1.70 m A-posed
skeleton. Its geometry is known in closed form in its own *canonical* frame (Z up, metres,
facing +Y, its left at -X, soles at z = 0, head top at z = HEIGHT), and each builder authors it
in the frame a converter would use, with the transforms above the SkelRoot that undo it.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
from pxr import Gf, Sdf, Usd, UsdGeom, UsdLux, UsdShade, UsdSkel, Vt

HEIGHT = 1.70
HEAD_TOP = np.array([0.0, 0.0, HEIGHT])

# key: (parent key, position in the canonical frame, metres)
_CANON = {
    "pelvis": (None, (0.0, 0.0, 0.95)),
    "spine": ("pelvis", (0.0, 0.0, 1.05)),
    "spine1": ("spine", (0.0, 0.0, 1.15)),
    "chest": ("spine1", (0.0, 0.0, 1.28)),
    "neck": ("chest", (0.0, 0.0, 1.45)),
    "head": ("neck", (0.0, 0.0, 1.53)),
}
for _s, _x in (("l", -1.0), ("r", 1.0)):
    _CANON.update({
        f"{_s}_clavicle": ("chest", (0.05 * _x, 0.0, 1.40)),
        f"{_s}_shoulder": (f"{_s}_clavicle", (0.17 * _x, 0.0, 1.40)),
        f"{_s}_elbow": (f"{_s}_shoulder", (0.19 * _x, 0.0, 1.12)),
        f"{_s}_wrist": (f"{_s}_elbow", (0.20 * _x, 0.0, 0.88)),
        f"{_s}_hip": ("pelvis", (0.10 * _x, 0.0, 0.90)),
        f"{_s}_knee": (f"{_s}_hip", (0.10 * _x, 0.02, 0.50)),
        f"{_s}_ankle": (f"{_s}_knee", (0.10 * _x, 0.0, 0.09)),
        f"{_s}_toe": (f"{_s}_ankle", (0.10 * _x, 0.13, 0.02)),
    })
KEYS = list(_CANON)
PARENTS = {k: parent for k, (parent, _) in _CANON.items()}


def _names(style: str) -> dict[str, str]:
    """Joint names of a naming style, per canonical key."""
    if style == "mixamo":  # Mixamo rig after an FBX -> glTF -> USD conversion (':' becomes '_')
        base = {"pelvis": "Hips", "spine": "Spine", "spine1": "Spine1", "chest": "Spine2", "neck": "Neck", "head": "Head"}
        for s, side in (("l", "Left"), ("r", "Right")):
            base.update({f"{s}_clavicle": f"{side}Shoulder", f"{s}_shoulder": f"{side}Arm", f"{s}_elbow": f"{side}ForeArm",
                         f"{s}_wrist": f"{side}Hand", f"{s}_hip": f"{side}UpLeg", f"{s}_knee": f"{side}Leg",
                         f"{s}_ankle": f"{side}Foot", f"{s}_toe": f"{side}ToeBase"})
        return {k: "mixamorig_" + v for k, v in base.items()}
    if style == "smpl":  # SMPL as many codebases name it: L_Foot is the toe joint, L_Collar the clavicle
        base = {"pelvis": "pelvis", "spine": "spine1", "spine1": "spine2", "chest": "spine3", "neck": "neck", "head": "head"}
        for s in "lr":
            S = s.upper()
            base.update({f"{s}_clavicle": f"{S}_Collar", f"{s}_shoulder": f"{S}_Shoulder", f"{s}_elbow": f"{S}_Elbow",
                         f"{s}_wrist": f"{S}_Wrist", f"{s}_hip": f"{S}_Hip", f"{s}_knee": f"{S}_Knee",
                         f"{s}_ankle": f"{S}_Ankle", f"{s}_toe": f"{S}_Foot"})
        return base
    if style == "cesium":  # anonymous numbered names: nothing to recognise, sides included
        return {k: f"joint_{i}" for i, k in enumerate(KEYS)}
    if style == "numbered":  # as in Khronos' CesiumMan: numbered joints per chain, sides as '_L_' words
        base = {"pelvis": "Skeleton_torso_joint_1", "spine": "Skeleton_torso_joint_2", "spine1": "torso_joint_3",
                "chest": "torso_joint_4", "neck": "Skeleton_neck_joint_1", "head": "Skeleton_neck_joint_2"}
        for s in "lr":
            S = s.upper()
            base.update({f"{s}_clavicle": f"Skeleton_arm_joint_{S}__1_", f"{s}_shoulder": f"Skeleton_arm_joint_{S}__2_",
                         f"{s}_elbow": f"Skeleton_arm_joint_{S}__3_", f"{s}_wrist": f"Skeleton_arm_joint_{S}__4_",
                         f"{s}_hip": f"leg_joint_{S}_1", f"{s}_knee": f"leg_joint_{S}_2", f"{s}_ankle": f"leg_joint_{S}_3",
                         f"{s}_toe": f"leg_joint_{S}_5"})
        return base
    raise ValueError(style)


def canon_position(key: str) -> np.ndarray:
    return np.array(_CANON[key][1], float)


def _boxes(keys=KEYS) -> list[tuple[str, np.ndarray, np.ndarray]]:
    """(joint key, lo, hi) of each box, canonical frame: soles at 0, head top at HEIGHT."""
    P = {k: canon_position(k) for k in KEYS}
    out = [("head", np.array([-0.09, -0.10, 1.50]), np.array([0.09, 0.10, HEIGHT])),
           ("pelvis", np.array([-0.15, -0.10, 0.85]), np.array([0.15, 0.10, 1.05]))]

    def seg(key, end, w):
        a, b = P[key], P[end] if isinstance(end, str) else np.asarray(end, float)
        out.append((key, np.minimum(a, b) - w, np.maximum(a, b) + w))

    seg("spine", "spine1", 0.12)
    seg("spine1", "chest", 0.13)
    seg("chest", "neck", 0.14)
    seg("neck", "head", 0.045)
    for s in "lr":
        seg(f"{s}_clavicle", f"{s}_shoulder", 0.04)
        seg(f"{s}_shoulder", f"{s}_elbow", 0.045)
        seg(f"{s}_elbow", f"{s}_wrist", 0.04)
        seg(f"{s}_wrist", P[f"{s}_wrist"] - [0, 0, 0.1], 0.035)
        seg(f"{s}_hip", f"{s}_knee", 0.065)
        seg(f"{s}_knee", f"{s}_ankle", 0.05)
        x = P[f"{s}_ankle"][0]
        out.append((f"{s}_ankle", np.array([x - 0.05, -0.05, 0.0]), np.array([x + 0.05, 0.13, 0.11])))
        out.append((f"{s}_toe", np.array([x - 0.05, 0.13, 0.0]), np.array([x + 0.05, 0.20, 0.05])))
    return [b for b in out if b[0] in keys]


def box_mesh(keys=KEYS):
    """(points (N,3) canonical, faceVertexCounts, faceVertexIndices, joint key per point) of the
    boxes of joints ``keys``."""
    pts, counts, idx, keys_out = [], [], [], []
    faces = [[0, 1, 3, 2], [4, 6, 7, 5], [0, 4, 5, 1], [2, 3, 7, 6], [0, 2, 6, 4], [1, 5, 7, 3]]
    for key, lo, hi in _boxes(keys):
        base = len(pts)
        pts += [[(lo, hi)[i][0], (lo, hi)[j][1], (lo, hi)[k][2]] for i in (0, 1) for j in (0, 1) for k in (0, 1)]
        counts += [4] * 6
        idx += [base + v for f in faces for v in f]
        keys_out += [key] * 8
    return np.array(pts, float), counts, idx, keys_out


def _rotation(rng) -> np.ndarray:
    q, _ = np.linalg.qr(rng.normal(size=(3, 3)))
    return q * np.sign(np.linalg.det(q))


def _gf(m: np.ndarray) -> Gf.Matrix4d:
    return Gf.Matrix4d(*np.asarray(m, float).T.ravel().tolist())  # column-vector 4x4 -> USD row-vector


def write_character(path, style: str = "mixamo", *, up: str = "Y", meters_per_unit: float = 1.0,
                    content: np.ndarray = np.eye(4), above=(), seed: int = 0, bind_scale: float = 1.0,
                    bind_mesh: bool = True, blend_shape: bool = False, textured: bool = False,
                    drop: tuple[str, ...] = (), root_joint: bool = False, geom_bind: np.ndarray | None = None) -> str:
    """Write a character file; returns the SkelRoot's path.

    ``content`` (4x4, column vectors) maps the canonical frame to the skeleton's space (the
    converter's axes and units); ``above`` is a list of (op, value) xformOps authored, in order, on
    an Xform /Root above the SkelRoot (('rotateX', -90), ('scale', 0.01), ...). Joint bind frames
    get random orientations (as exported rigs have); ``bind_scale`` = 0 puts every joint at the
    origin (a degenerate bind pose). ``textured``: a UsdPreviewSurface whose colour is a PNG texture
    beside the file (:data:`TEXTURE_RGB`), under ``/Root/Materials`` outside the SkelRoot, as glTF
    converters write it, and a camera and a light beside the character (which a placed person must not
    bring along). ``drop``: canonical joints left out, with the joints and boxes below them.
    ``root_joint``: an Unreal-style ``root`` joint on the ground under the pelvis, parent of it.
    ``geom_bind`` (4x4, column vectors): the mesh's points are authored in another space and its
    geomBindTransform (this matrix) takes them to the skeleton's, as Blender's exporter writes it."""
    rng = np.random.default_rng(seed)
    stage = Usd.Stage.CreateNew(str(path))
    UsdGeom.SetStageUpAxis(stage, UsdGeom.Tokens.y if up == "Y" else UsdGeom.Tokens.z)
    UsdGeom.SetStageMetersPerUnit(stage, meters_per_unit)
    top = UsdGeom.Xform.Define(stage, "/Root")
    stage.SetDefaultPrim(top.GetPrim())
    for op, value in above:
        if op == "scale":
            top.AddScaleOp().Set(Gf.Vec3f(value, value, value))
        elif op == "translate":
            top.AddTranslateOp().Set(Gf.Vec3d(*value))
        else:
            getattr(top, f"Add{op[0].upper()}{op[1:]}Op")().Set(float(value))
    root = UsdSkel.Root.Define(stage, "/Root/Character")
    names = _names(style)
    keys_kept = [k for k in KEYS if not any(d == k or _below(k, d) for d in drop)]
    parents = {k: _CANON[k][0] for k in keys_kept}
    where = {k: canon_position(k) for k in keys_kept}
    if root_joint:
        keys_kept, names = ["root"] + keys_kept, {**names, "root": "root"}
        parents.update(root=None, pelvis="root")
        where["root"] = np.zeros(3)
    joints, bind, rest = [], [], []
    world = {}
    for key in keys_kept:
        parent = parents[key]
        joints.append(f"{joints[keys_kept.index(parent)]}/{names[key]}" if parent else names[key])
        m = np.eye(4)  # rigid joint frames in the converter's space: a random orientation, at the joint
        m[:3, :3] = _rotation(rng)
        m[:3, 3] = content[:3, :3] @ where[key] * bind_scale + content[:3, 3]
        world[key] = m
        bind.append(world[key])
        rest.append(np.linalg.inv(world[parent]) @ world[key] if parent else world[key])
    skel = UsdSkel.Skeleton.Define(stage, "/Root/Character/Skeleton")
    skel.CreateJointsAttr(Vt.TokenArray(joints))
    skel.CreateBindTransformsAttr(Vt.Matrix4dArray([_gf(m) for m in bind]))
    skel.CreateRestTransformsAttr(Vt.Matrix4dArray([_gf(m) for m in rest]))
    points, counts, indices, keys = box_mesh(keys_kept)
    pts = points @ content[:3, :3].T + content[:3, 3]
    if geom_bind is not None:
        inv = np.linalg.inv(geom_bind)
        pts = pts @ inv[:3, :3].T + inv[:3, 3]
    mesh = UsdGeom.Mesh.Define(stage, "/Root/Character/Body")
    mesh.CreatePointsAttr(Vt.Vec3fArray.FromNumpy(pts.astype(np.float32)))
    mesh.CreateFaceVertexCountsAttr(counts)
    mesh.CreateFaceVertexIndicesAttr(indices)
    mesh.CreateSubdivisionSchemeAttr(UsdGeom.Tokens.none)
    mesh.CreateDisplayColorPrimvar(UsdGeom.Tokens.constant).Set(Vt.Vec3fArray([Gf.Vec3f(0.7, 0.5, 0.4)]))
    if bind_mesh:
        binding = UsdSkel.BindingAPI.Apply(mesh.GetPrim())
        binding.CreateSkeletonRel().SetTargets([skel.GetPath()])
        binding.CreateJointIndicesPrimvar(False, 1).Set(Vt.IntArray([keys_kept.index(k) for k in keys]))
        binding.CreateJointWeightsPrimvar(False, 1).Set(Vt.FloatArray([1.0] * len(keys)))
        binding.CreateGeomBindTransformAttr(_gf(np.eye(4) if geom_bind is None else geom_bind))
        if blend_shape:
            shape = UsdSkel.BlendShape.Define(stage, "/Root/Character/Body/Smile")
            shape.CreateOffsetsAttr(Vt.Vec3fArray([Gf.Vec3f(0, 0, 1)]))
            shape.CreatePointIndicesAttr(Vt.IntArray([0]))
            binding.CreateBlendShapesAttr(Vt.TokenArray(["smile"]))
            binding.CreateBlendShapeTargetsRel().SetTargets([shape.GetPath()])
    if textured:
        _texture(stage, mesh, len(counts), Path(path))
    stage.Save()
    return str(root.GetPath())


#: The texture's colour (sRGB bytes) and its value in linear light, as a render shows it.
TEXTURE_RGB = (40, 200, 60)


def _texture(stage: Usd.Stage, mesh: UsdGeom.Mesh, faces: int, path: Path) -> None:
    """A PNG texture beside ``path`` on ``mesh`` through a material under /Root/Materials; a camera
    and a light under /Root beside the character."""
    from PIL import Image

    png = path.with_name(path.stem + "_skin.png")
    Image.new("RGB", (4, 4), TEXTURE_RGB).save(png)
    st = UsdGeom.PrimvarsAPI(mesh).CreatePrimvar("st", Sdf.ValueTypeNames.TexCoord2fArray, UsdGeom.Tokens.faceVarying)
    st.Set(Vt.Vec2fArray([Gf.Vec2f(u, v) for _ in range(faces) for u, v in ((0, 0), (1, 0), (1, 1), (0, 1))]))
    UsdGeom.Scope.Define(stage, "/Root/Materials")
    mat = UsdShade.Material.Define(stage, "/Root/Materials/Skin")
    surface = UsdShade.Shader.Define(stage, "/Root/Materials/Skin/Surface")
    surface.CreateIdAttr("UsdPreviewSurface")
    reader = UsdShade.Shader.Define(stage, "/Root/Materials/Skin/UV")
    reader.CreateIdAttr("UsdPrimvarReader_float2")
    reader.CreateInput("varname", Sdf.ValueTypeNames.String).Set("st")
    tex = UsdShade.Shader.Define(stage, "/Root/Materials/Skin/Colour")
    tex.CreateIdAttr("UsdUVTexture")
    tex.CreateInput("file", Sdf.ValueTypeNames.Asset).Set(f"./{png.name}")
    tex.CreateInput("sourceColorSpace", Sdf.ValueTypeNames.Token).Set("sRGB")
    tex.CreateInput("st", Sdf.ValueTypeNames.Float2).ConnectToSource(reader.ConnectableAPI(), "result")
    surface.CreateInput("diffuseColor", Sdf.ValueTypeNames.Color3f).ConnectToSource(tex.ConnectableAPI(), "rgb")
    surface.CreateInput("roughness", Sdf.ValueTypeNames.Float).Set(0.8)
    mat.CreateSurfaceOutput().ConnectToSource(surface.ConnectableAPI(), "surface")
    UsdShade.MaterialBindingAPI.Apply(mesh.GetPrim()).Bind(mat)
    UsdGeom.Camera.Define(stage, "/Root/Camera").AddTranslateOp().Set(Gf.Vec3d(0, 100, 400))
    UsdLux.DistantLight.Define(stage, "/Root/Light").CreateIntensityAttr(50000.0)


def _below(key: str, ancestor: str) -> bool:
    parent = PARENTS[key]
    while parent is not None:
        if parent == ancestor:
            return True
        parent = PARENTS[parent]
    return False


def scaled(s: float, rot_z_deg: float = 0.0) -> np.ndarray:
    """4x4: a turn about Z then a uniform scale (canonical metres -> a converter's units)."""
    a = np.radians(rot_z_deg)
    m = np.eye(4)
    m[:3, :3] = s * np.array([[np.cos(a), -np.sin(a), 0], [np.sin(a), np.cos(a), 0], [0, 0, 1]])
    return m


def gltf_mixamo(path) -> str:
    """A Mixamo rig as a glTF converter writes it: a Y-up metre stage whose content is Z-up
    centimetres facing -Y (as authored in Blender/FBX) under an Xform with rotateX -90 and scale 0.01."""
    return write_character(path, "mixamo", up="Y", meters_per_unit=1.0, content=scaled(100.0, 180.0),
                           above=[("rotateX", -90.0), ("scale", 0.01)])


def smpl_cm(path) -> str:
    """An SMPL-named character in a Z-up centimetre stage whose content is Y-up (as from a glTF
    source), stood up by a rotateX 90, turned by a rotateZ and moved by a translate on the Xform
    above its SkelRoot."""
    lie = np.eye(4)
    lie[1:3, 1:3] = [[0.0, 1.0], [-1.0, 0.0]]  # rotateX -90: canonical Z-up content -> Y-up
    return write_character(path, "smpl", up="Z", meters_per_unit=0.01, content=scaled(100.0) @ lie,
                           above=[("translate", (300.0, -200.0, 40.0)), ("rotateZ", -90.0), ("rotateX", 90.0)], seed=1)


def gltf_numbered(path) -> str:
    """CesiumMan-shaped: numbered joints, Y-up centimetres, content Z-up facing -Y stood up by a
    rotateX -90 above the SkelRoot, textured."""
    return write_character(path, "numbered", up="Y", meters_per_unit=0.01, content=scaled(100.0, 180.0),
                           above=[("rotateX", -90.0)], textured=True, seed=3)


def yup_cm_set(path: Path) -> None:
    """A set for characters: tests/support/world_stages' scene on a Y-up centimetre stage, 72 frames (ground at world z = 0)."""
    from .world_stages import write_world_stage

    stage = write_world_stage(path, "Y", 0.01)
    stage.SetEndTimeCode(72)
    stage.Save()


# BrainStem (Khronos glTF-Sample-Models 2.0/BrainStem/glTF/BrainStem.gltf, COLLADA2GLTF output): its
# node tree, unnamed nodes, glTF translation and rotation (x, y, z, w) per node as the file gives
# them (scales ~1 dropped). Above the skeleton: node 0, a Z-up -> Y-up matrix, and node 2, a rotation
# of +90 degrees about X; joints are nodes 3-20. Its rest pose is a T-pose (hands 1 m out, a
# 2 m span) on a robot's proportions: shoulders 0.42 m out from the chest joint, a 0.19 m upper arm,
# a 0.41 m forearm and hand whose left ends in three finger joints and whose right ends at the
# forearm joint (no hand joint), legs hip - thigh - shin - foot - toe, chest - head.
_BRAINSTEM = {  # node: (parent node, translation, rotation xyzw)
    3: (None, (0.0, 0.9148268, 0.0), (0.0, -0.00067961, 0.0, -0.99999976)),  # hip
    4: (3, (0.1415491, -0.0393192, 0.0), (0.73884153, 1.437e-7, -0.67168546, -0.05441156)),  # left thigh
    5: (4, (0.0, 0.3586178, 0.0), (0.02620056, -0.52830058, 0.01508804, -0.84851897)),  # left shin
    6: (5, (0.0, 0.3968967, 0.0), (0.45504338, -0.16150843, -0.07667787, -0.87233657)),  # left foot
    7: (6, (0.0, 0.1285487, 0.0), (0.90336329, 0.0, 0.0, -0.42887634)),  # left toe
    8: (3, (-0.1415491, -0.0393192, 0.0), (0.73884153, -1.437e-7, 0.67168546, -0.05441156)),
    9: (8, (0.0, 0.3586178, 0.0), (0.02620056, 0.52830058, -0.01508804, -0.84851897)),
    10: (9, (0.0, 0.3968967, 0.0), (0.45504338, 0.16150843, 0.07667787, -0.87233657)),
    11: (10, (0.0, 0.1285487, 0.0), (0.90336329, 0.0, 0.0, -0.42887634)),
    12: (3, (0.0, 0.1074722, -0.0235915), (0.0, 0.0, 0.0, -1.0)),  # chest
    13: (12, (0.4194048, 0.3407668, -0.0131064), (0.00977804, 4.916e-7, 0.69207245, -0.72176194)),  # left shoulder
    14: (13, (0.0, 0.1857225, 0.0), (-0.00977802, -4.71e-7, -0.69207239, -0.72176188)),  # left forearm
    15: (14, (0.4125711, -0.0216771, 0.0550150), (0.0, 0.0, 0.0, -1.0)),  # thumb
    16: (14, (0.4119341, 0.0215858, 0.0576437), (0.0, 0.0, 0.0, -1.0)),  # pinky
    17: (14, (0.4094892, 0.0027068, 0.0157277), (0.0, 0.0, 0.0, -1.0)),  # middle finger
    18: (12, (-0.4194049, 0.3407665, -0.0131063), (0.00934915, -4.43e-8, -0.68245828, -0.7308647)),  # right shoulder
    19: (18, (0.0, 0.1918197, 0.0), (-0.00934914, 3.41e-8, 0.68245828, -0.7308647)),  # right forearm (no hand joint)
    20: (12, (0.0, 0.5242561, -0.0157277), (0.0, 0.0, 0.0, -1.0)),  # head
}


def _quat(xyzw) -> np.ndarray:
    x, y, z, w = np.asarray(xyzw, float) / np.linalg.norm(xyzw)
    return np.array([[1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
                     [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
                     [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)]])


def brainstem_joints() -> tuple[list[str], dict[int, np.ndarray]]:
    """(joint paths 'node_3/node_12/...', node -> skeleton-space rest matrix (4x4, column vectors))
    of the BrainStem-shaped skeleton."""
    world, paths = {}, {}
    for node, (parent, t, q) in _BRAINSTEM.items():
        local = np.eye(4)
        local[:3, :3], local[:3, 3] = _quat(q), t
        world[node] = world[parent] @ local if parent else local
        paths[node] = f"{paths[parent]}/node_{node}" if parent else f"node_{node}"
    return [paths[n] for n in _BRAINSTEM], world


def brainstem_like(path) -> np.ndarray:
    """Write a character shaped like BrainStem as a glTF -> USD converter writes it: a Y-up metre
    stage, the glTF's node 0 matrix and node 2 rotation on Xforms above the SkelRoot, anonymous joint
    names (node_N), bind = rest = the glTF's node transforms (arms straight out), a box per bone
    rigidly skinned to its joint (the right hand's box beyond its last joint, mirroring the left).
    Returns the skeleton-space T-pose hand joints' positions (2, 3: left, right)."""
    joints, world = brainstem_joints()
    nodes = list(_BRAINSTEM)
    P = {n: world[n][:3, 3] for n in nodes}
    P[21] = P[17] * [-1.0, 1.0, 1.0]  # the right hand's end, where the left's middle finger is mirrored
    stage = Usd.Stage.CreateNew(str(path))
    UsdGeom.SetStageUpAxis(stage, UsdGeom.Tokens.y)
    UsdGeom.SetStageMetersPerUnit(stage, 1.0)
    top = UsdGeom.Xform.Define(stage, "/Root")
    stage.SetDefaultPrim(top.GetPrim())
    top.AddTransformOp().Set(_gf(np.array([[1, 0, 0, 0], [0, 0, 1, 0], [0, -1, 0, 0], [0, 0, 0, 1.0]])))  # node 0
    node2 = UsdGeom.Xform.Define(stage, "/Root/node_2")
    node2.AddTransformOp().Set(_gf(np.block([[_quat((-0.70710665, 0.00048056, 0.00048056, -0.70710653)), np.zeros((3, 1))],
                                             [np.zeros((1, 3)), np.ones((1, 1))]])))
    root = UsdSkel.Root.Define(stage, "/Root/node_2/BrainStem")
    skel = UsdSkel.Skeleton.Define(stage, root.GetPath().AppendChild("Skeleton"))
    skel.CreateJointsAttr(Vt.TokenArray(joints))
    skel.CreateBindTransformsAttr(Vt.Matrix4dArray([_gf(world[n]) for n in nodes]))
    rest = [np.linalg.inv(world[_BRAINSTEM[n][0]]) @ world[n] if _BRAINSTEM[n][0] else world[n] for n in nodes]
    skel.CreateRestTransformsAttr(Vt.Matrix4dArray([_gf(m) for m in rest]))
    # (joint node, from, to, half width) of each box: torso, head, limbs, feet
    bones = [(3, 3, 12, 0.15), (12, 12, 20, 0.2), (20, 20, 20, 0.12), (13, 13, 14, 0.08), (14, 14, 17, 0.06),
             (18, 18, 19, 0.08), (19, 19, 21, 0.06)]
    for thigh, shin, foot, toe in ((4, 5, 6, 7), (8, 9, 10, 11)):
        bones += [(thigh, thigh, shin, 0.07), (shin, shin, foot, 0.05), (foot, foot, toe, 0.05)]
    pts, counts, idx, ji = [], [], [], []
    faces = [[0, 1, 3, 2], [4, 6, 7, 5], [0, 4, 5, 1], [2, 3, 7, 6], [0, 2, 6, 4], [1, 5, 7, 3]]
    for joint, a, b, w in bones:
        lo, hi = np.minimum(P[a], P[b]) - w, np.maximum(P[a], P[b]) + w
        lo[1] = max(lo[1], 0.0)  # soles on the ground (y = 0)
        base = len(pts)
        pts += [[(lo, hi)[i][0], (lo, hi)[j][1], (lo, hi)[k][2]] for i in (0, 1) for j in (0, 1) for k in (0, 1)]
        counts += [4] * 6
        idx += [base + v for f in faces for v in f]
        ji += [nodes.index(joint)] * 8
    mesh = UsdGeom.Mesh.Define(stage, root.GetPath().AppendChild("Body"))
    mesh.CreatePointsAttr(Vt.Vec3fArray.FromNumpy(np.array(pts, np.float32)))
    mesh.CreateFaceVertexCountsAttr(counts)
    mesh.CreateFaceVertexIndicesAttr(idx)
    mesh.CreateSubdivisionSchemeAttr(UsdGeom.Tokens.none)
    binding = UsdSkel.BindingAPI.Apply(mesh.GetPrim())
    binding.CreateSkeletonRel().SetTargets([skel.GetPath()])
    binding.CreateJointIndicesPrimvar(False, 1).Set(Vt.IntArray(ji))
    binding.CreateJointWeightsPrimvar(False, 1).Set(Vt.FloatArray([1.0] * len(ji)))
    binding.CreateGeomBindTransformAttr(_gf(np.eye(4)))
    stage.Save()
    return np.array([P[17], P[21]])

"""A procedural human as UsdSkel: a smooth skinned body on a 19-joint skeleton, labelled ``person``.

The character frame is Z up, facing +Y, metres, with the origin on the ground between the feet
(so the character's right is +X). Joint rest orientations are the identity: every joint's
rest transform is a pure translation, which keeps animation maths simple and any retargeting
(see lfusd.author.gait) exact.

Proportions follow standard anthropometric fractions of stature (Drillis & Contini); ``build``
in [0, 1] widens the body (0 slim, 0.5 average, 1 heavy). ``look`` seeds the rest of a person's
appearance: hip, waist and chest girth, hair, skin tone and clothes (a top with long, short or no
sleeves, trousers or shorts, shoes). The skin is one closed surface, a control cage subdivided here
(lfusd.author.body); clothes are UsdPreviewSurface materials bound to face subsets of it, and the
hair is a closed layer over the scalp skinned like the skin beneath it. Joints depend on stature
alone, so every gait fits every look.
"""

from __future__ import annotations

import functools
from dataclasses import dataclass

import numpy as np
from pxr import Gf, Sdf, Usd, UsdGeom, UsdShade, UsdSkel, Vt

from ..errors import LfusdError
from .body import _R4, Cage
from .labels import set_class_label
from .stage import round_values

# (name, parent name) in parent-before-child order; UsdSkel joint paths are built from these.
_JOINTS = [
    ("pelvis", None),
    ("spine", "pelvis"),
    ("chest", "spine"),
    ("neck", "chest"),
    ("head", "neck"),
    ("l_shoulder", "chest"),
    ("l_elbow", "l_shoulder"),
    ("l_wrist", "l_elbow"),
    ("r_shoulder", "chest"),
    ("r_elbow", "r_shoulder"),
    ("r_wrist", "r_elbow"),
    ("l_hip", "pelvis"),
    ("l_knee", "l_hip"),
    ("l_ankle", "l_knee"),
    ("l_toe", "l_ankle"),
    ("r_hip", "pelvis"),
    ("r_knee", "r_hip"),
    ("r_ankle", "r_knee"),
    ("r_toe", "r_ankle"),
]
JOINT_NAMES = [n for n, _ in _JOINTS]
_PARENT = dict(_JOINTS)

ARM_OUT_DEG = 8.0
MESH_NAME = "Body"
SKELETON_NAME = "Skeleton"
ANIMATION_NAME = "Motion"


@dataclass(frozen=True)
class HumanSpec:
    """Stature in metres, build in [0, 1] and ``look``, the seed of shape details and clothes
    (None: derived from stature and build, so people of different sizes look different)."""

    height: float = 1.75
    build: float = 0.5
    look: int | None = None

    def seed(self) -> int:
        """The look's seed (from stature and build rounded to micrometres when ``look`` is None)."""
        if self.look is not None:
            return int(self.look)
        return int(round(self.height * 1e6)) * 1_000_003 + int(round(self.build * 1e6))

    def validate(self) -> None:
        if not 0.5 <= self.height <= 2.5:
            raise LfusdError(f"human height {self.height:g} m is outside 0.5-2.5 m; give a plausible stature")
        if not 0.0 <= self.build <= 1.0:
            raise LfusdError(f"human build {self.build:g} is outside 0-1; use 0 (slim) to 1 (heavy)")


def joint_paths() -> list[str]:
    """UsdSkel joint tokens ('pelvis/spine/chest', ...) in skeleton order."""
    out = []
    for name in JOINT_NAMES:
        chain = [name]
        while _PARENT[chain[-1]] is not None:
            chain.append(_PARENT[chain[-1]])
        out.append("/".join(reversed(chain)))
    return out


def parent_indices() -> np.ndarray:
    """Index of each joint's parent (-1 for the root)."""
    return np.array([-1 if p is None else JOINT_NAMES.index(p) for _, p in _JOINTS])


def rest_positions(spec: HumanSpec) -> dict[str, np.ndarray]:
    """Joint centres in the character frame (metres), plus end points 'head_top', hand and toe tips."""
    H = spec.height
    arm_out = np.radians(ARM_OUT_DEG)  # A-pose: arms hang slightly out from vertical
    p = {
        "pelvis": (0.0, 0.0, 0.555 * H),
        "spine": (0.0, -0.005 * H, 0.63 * H),
        "chest": (0.0, -0.005 * H, 0.72 * H),
        "neck": (0.0, -0.01 * H, 0.835 * H),
        "head": (0.0, 0.0, 0.895 * H),
        "head_top": (0.0, 0.0, 1.0 * H),
        "l_hip": (-0.052 * H, 0.0, 0.53 * H),
        "l_knee": (-0.052 * H, 0.005 * H, 0.285 * H),
        "l_ankle": (-0.052 * H, 0.0, 0.04 * H),
        "l_toe": (-0.056 * H, 0.1 * H, 0.012 * H),
        "l_toe_tip": (-0.058 * H, 0.128 * H, 0.012 * H),
        "l_shoulder": (-0.112 * H, -0.01 * H, 0.815 * H),
    }
    sh = np.array(p["l_shoulder"])
    down = np.array([-np.sin(arm_out), 0.0, -np.cos(arm_out)])
    p["l_elbow"] = tuple(sh + 0.186 * H * down)
    p["l_wrist"] = tuple(sh + (0.186 + 0.146) * H * down)
    p["l_hand_tip"] = tuple(sh + (0.186 + 0.146 + 0.108) * H * down)
    for k in [k for k in p if k.startswith("l_")]:
        x, y, z = p[k]
        p["r_" + k[2:]] = (-x, y, z)
    return {k: np.array(v, dtype=np.float64) for k, v in p.items()}


# Where each joint's bone ends (for skin weights): its child, or an end point.
_BONE_END = {
    "pelvis": "spine", "spine": "chest", "chest": "neck", "neck": "head", "head": "head_top",
    "l_shoulder": "l_elbow", "l_elbow": "l_wrist", "l_wrist": "l_hand_tip",
    "r_shoulder": "r_elbow", "r_elbow": "r_wrist", "r_wrist": "r_hand_tip",
    "l_hip": "l_knee", "l_knee": "l_ankle", "l_ankle": "l_toe", "l_toe": "l_toe_tip",
    "r_hip": "r_knee", "r_knee": "r_ankle", "r_ankle": "r_toe", "r_toe": "r_toe_tip",
}


# Which joints may influence each part (keeps, e.g., hands from following the hips).
_PART_JOINTS = {
    "torso": ["pelvis", "spine", "chest", "neck", "l_shoulder", "r_shoulder", "l_hip", "r_hip"],
    "neck": ["chest", "neck", "head"],
    "head": ["neck", "head"],
}
for _s in "lr":
    _PART_JOINTS[f"{_s}_leg"] = ["pelvis", f"{_s}_hip", f"{_s}_knee", f"{_s}_ankle"]
    _PART_JOINTS[f"{_s}_foot"] = [f"{_s}_ankle", f"{_s}_toe"]  # a rigid sole: no knee, which would sink it
    _PART_JOINTS[f"{_s}_arm"] = ["chest", f"{_s}_shoulder", f"{_s}_elbow", f"{_s}_wrist"]
    _PART_JOINTS[f"{_s}_hand"] = [f"{_s}_elbow", f"{_s}_wrist"]


def _segment_distance(p: np.ndarray, a: np.ndarray, b: np.ndarray) -> np.ndarray:
    ab = b - a
    t = np.clip(((p - a) @ ab) / max(float(ab @ ab), 1e-12), 0.0, 1.0)
    return np.linalg.norm(p - (a + t[:, None] * ab), axis=1)


def skin_weights(spec: HumanSpec, influences: int = 4, levels: int | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Skin weights of :func:`body_mesh`'s points: the cage's weights (inverse distance to the bones
    each part may follow), subdivided with the points, so they vary as smoothly as the surface.

    Returns (joint indices (N, k) int, weights (N, k) float summing to 1), the ``influences`` largest.
    """
    raw = _body(spec, levels)[4]
    # Rank rounded weights: weights equal in exact arithmetic differ in their last bit from CPU to
    # CPU, and the stable sort then breaks such ties by joint index, the same on every machine.
    raw = round_values(raw)
    order = np.argsort(-raw, axis=1, kind="stable")[:, :influences]
    w = np.take_along_axis(raw, order, axis=1)
    w /= w.sum(axis=1, keepdims=True)
    return order.astype(np.int32), w


SKIN_TONES = [(0.87, 0.70, 0.58), (0.80, 0.60, 0.46), (0.68, 0.48, 0.34), (0.55, 0.38, 0.26), (0.40, 0.27, 0.18), (0.28, 0.19, 0.13)]
HAIR = [(0.05, 0.04, 0.035), (0.18, 0.11, 0.06), (0.35, 0.22, 0.12), (0.70, 0.55, 0.30), (0.55, 0.55, 0.55), (0.45, 0.16, 0.06)]
TOPS = [(0.70, 0.08, 0.06), (0.08, 0.20, 0.62), (0.85, 0.85, 0.82), (0.85, 0.65, 0.08), (0.10, 0.38, 0.18), (0.12, 0.12, 0.13),
        (0.55, 0.25, 0.55), (0.95, 0.45, 0.15), (0.35, 0.60, 0.80), (0.55, 0.50, 0.40), (0.85, 0.45, 0.55), (0.30, 0.30, 0.32)]
BOTTOMS = [(0.12, 0.20, 0.38), (0.08, 0.08, 0.09), (0.55, 0.48, 0.35), (0.35, 0.35, 0.37), (0.30, 0.20, 0.12), (0.15, 0.30, 0.55)]
SHOES = [(0.05, 0.05, 0.05), (0.85, 0.85, 0.85), (0.30, 0.18, 0.10), (0.20, 0.20, 0.25)]
REGIONS = ("skin", "hair", "top", "bottom", "shoes")
SHOE_TOP = 0.055  # fraction of stature: shoes cover the feet and ankles up to here


def appearance(spec: HumanSpec) -> dict:
    """The look of ``spec``: girth factors, colours (linear RGB) of skin, hair and clothes, sleeve
    length (fraction of the arm covered) and leg cover (trousers 1, shorts 0.45)."""
    rng = np.random.default_rng([spec.seed() & 0xFFFFFFFF, spec.seed() >> 32, 16])
    pick = lambda table: tuple(float(c) for c in table[int(rng.integers(len(table)))])  # noqa: E731
    return {
        "hips": float(rng.uniform(0.92, 1.12)), "waist": float(rng.uniform(0.9, 1.1)),
        "chest": float(rng.uniform(0.92, 1.08)), "belly": float(rng.uniform(0.95, 1.25)),
        "skin": pick(SKIN_TONES), "hair": pick(HAIR) if rng.random() < 0.9 else None,
        "hair_length": float(rng.uniform(0.0, 1.0)),
        "top": pick(TOPS), "bottom": pick(BOTTOMS), "shoes": pick(SHOES),
        "sleeves": float(rng.choice([1.0, 1.0, 0.45, 0.12])), "legs": float(rng.choice([1.0, 1.0, 1.0, 0.45])),
    }


# -- the smooth body ---------------------------------------------------------------------------------
# Torso, neck and head: rings of 8 cage points (z, corner half-width, front, back; fractions of
# stature, before girth), the four points of each of the front and back rows at x = +-a and +-a/3.
_TORSO = [
    (0.465, 0.100, 0.050, 0.052), (0.50, 0.104, 0.058, 0.070), (0.55, 0.100, 0.058, 0.062),
    (0.60, 0.084, 0.055, 0.052), (0.65, 0.086, 0.058, 0.050), (0.70, 0.096, 0.064, 0.055),
    (0.745, 0.100, 0.066, 0.058), (0.80, 0.100, 0.055, 0.055), (0.83, 0.082, 0.035, 0.045),
]
_ARMPIT = 6  # the arms grow out of the sides between torso rings 6 and 7
_NECK = [(0.855, 0.033, 0.033, 0.035), (0.877, 0.030, 0.030, 0.030)]
_HEAD = [(0.895, 0.042, 0.062, 0.040), (0.93, 0.052, 0.070, 0.062), (0.965, 0.052, 0.062, 0.064), (0.995, 0.036, 0.040, 0.046)]
# Legs: rings of 4 around the bone line (z, half-width across, front, back; round radii).
_LEG = [(0.43, 0.050, 0.050, 0.055), (0.38, 0.046, 0.048, 0.048), (0.33, 0.040, 0.040, 0.040), (0.29, 0.034, 0.036, 0.034),
        (0.25, 0.034, 0.032, 0.038), (0.20, 0.034, 0.030, 0.042), (0.13, 0.026, 0.025, 0.028), (0.075, 0.022, 0.022, 0.024)]
ARM_GAP = 0.008  # fraction of stature kept between the hanging arms and the torso
THIGH_GAP = 0.005  # fraction of stature kept between the thighs, so legs swinging past each other never touch


def _ring8(z, a, f, b, yc, m=None):
    m = a / 3.0 if m is None else m
    return [(a, yc - b, z), (a, yc + f, z), (m, yc + f, z), (-m, yc + f, z), (-a, yc + f, z), (-a, yc - b, z), (-m, yc - b, z), (m, yc - b, z)]


def body_cage(spec: HumanSpec) -> Cage:
    """The control cage of the body (character frame, metres), part names per point and quad."""
    H = spec.height
    w = 0.8 + 0.5 * spec.build  # girth factor
    arm_w = min(w, 1.1)  # arms thicken less: they hang close to the torso
    look = appearance(spec)
    P = {k: v / H for k, v in rest_positions(spec).items()}  # the cage is laid out in fractions of stature
    cage = Cage()
    rings = []
    for k, (z, a, f, b) in enumerate(_TORSO):
        g = look["hips"] if z < 0.56 else look["waist"] if z < 0.68 else look["chest"]
        belly = look["belly"] if 0.58 < z < 0.68 else 1.0
        m = 0.012 if k == 0 else None  # the crotch between the legs' openings
        a = a * w * g
        if 0.5 <= z <= _TORSO[_ARMPIT + 1][0]:  # no wider than the hanging arms allow (a heavy body grows deeper instead)
            arm = P["r_shoulder"][0] + (P["r_shoulder"][2] - min(z, _TORSO[_ARMPIT][0])) * np.tan(np.radians(ARM_OUT_DEG))
            a = min(a, (arm - 0.033 * _R4 * arm_w - ARM_GAP) / 0.89)  # 0.89: the subdivided side lies 0.89 a out
        rings.append(cage.ring(_ring8(z, a, f * w * g * belly, b * w * g, -0.005, m), "torso"))
    for z, a, f, b in _NECK:
        rings.append(cage.ring(_ring8(z, a * min(w, 1.1), f * min(w, 1.1), b * min(w, 1.1), -0.008), "neck"))
    for z, a, f, b in _HEAD:
        rings.append(cage.ring(_ring8(z, a, f, b, 0.0), "head"))
    for k in range(len(rings) - 1):
        cage.loft(rings[k], rings[k + 1], cage.point_part[rings[k + 1][0]], skip=(0, 4) if k == _ARMPIT else ())
    top, bottom = rings[-1], rings[0]
    for q in ([0, 1, 2, 7], [7, 2, 3, 6], [6, 3, 4, 5]):
        cage.quad([top[i] for i in q], "head")
    cage.quad([bottom[i] for i in (7, 2, 3, 6)], "torso")  # the crotch
    X, Y, Z = np.eye(3)
    arm_out = np.radians(ARM_OUT_DEG)
    for side, s, leg_loop, arm_side in (("r", 1.0, (0, 1, 2, 7), 0), ("l", -1.0, (6, 3, 4, 5), 4)):
        # Leg and foot, out of the torso's bottom; u points out, v forward (then up along the foot).
        out = s * X
        knee, ankle = P[f"{side}_knee"], P[f"{side}_ankle"]
        frames = []
        for z, rx, f, b in _LEG:
            t = (z - knee[2]) / (0.53 - knee[2]) if z > knee[2] else (z - ankle[2]) / (knee[2] - ankle[2]) - 1.0
            y = knee[1] * (1 - abs(t))
            x = s * (abs(knee[0]) + 0.004 * max(t, 0.0))
            rx = min(rx * w, abs(x) - THIGH_GAP / 2)  # heavy thighs grow forward and back, not into each other
            frames.append((f"{side}_leg", (x, y + (f - b) * w / 2, z), out, Y, (rx * _R4, rx * _R4), ((f + b) * w / 2 * _R4,) * 2))
        ax = s * abs(ankle[0])
        diag = (Y + Z) / np.sqrt(2.0)
        frames += [
            (f"{side}_foot", (ax, 0.0, 0.045), out, Y, (0.024, 0.024), (0.030, 0.026)),
            (f"{side}_foot", (ax, 0.005, 0.02), out, diag, (0.028, 0.028), (0.055, 0.030)),
            (f"{side}_foot", (ax + s * 0.001, 0.05, 0.022), out, Z, (0.030, 0.032), (0.032, 0.026)),
            (f"{side}_foot", (ax + s * 0.003, 0.095, 0.015), out, Z, (0.030, 0.034), (0.025, 0.018)),
            (f"{side}_foot", (ax + s * 0.005, 0.122, 0.010), out, Z, (0.020, 0.022), (0.016, 0.010)),
        ]
        cage.branch([bottom[i] for i in leg_loop], (out, Y), frames, cap=f"{side}_foot")
        # Arm and hand, out of the chest's side; u points out and up (across the arm), v forward.
        sh, el, wr = (P[f"{side}_{j}"] for j in ("shoulder", "elbow", "wrist"))
        d = np.array([s * np.sin(arm_out), 0.0, -np.cos(arm_out)])
        o = np.array([s * np.cos(arm_out), 0.0, np.sin(arm_out)])
        r = lambda a, b: ((a * arm_w * _R4, a * arm_w * _R4), (b * arm_w * _R4, b * arm_w * _R4))  # noqa: E731
        a_ring, b_ring = rings[_ARMPIT], rings[_ARMPIT + 1]
        loop = [a_ring[arm_side], a_ring[arm_side + 1], b_ring[arm_side + 1], b_ring[arm_side]]
        # The deltoid: a ring from just out of and below the armpit (the opening's lower edge, so
        # the arm's inner side runs down from it, without a fold) up to the top of the shoulder.
        pit = np.array([cage.points[loop[0]][0] + s * 0.015, sh[1], _TORSO[_ARMPIT][0] - 0.008])
        top = np.array([sh[0] + s * 0.03, sh[1], sh[2] + 0.006])
        tilt, reach = (top - pit) / np.linalg.norm(top - pit), np.linalg.norm(top - pit) / 2
        frames = [
            (f"{side}_arm", (pit + top) / 2, tilt, Y, (reach, reach), (0.042 * arm_w, 0.042 * arm_w)),
            (f"{side}_arm", sh + 0.5 * (el - sh), o, Y, *r(0.031, 0.033)),
            (f"{side}_arm", sh + 0.85 * (el - sh), o, Y, *r(0.026, 0.027)),
            (f"{side}_arm", el, o, Y, *r(0.025, 0.025)),
            (f"{side}_arm", el + 0.3 * (wr - el), o, Y, *r(0.027, 0.025)),
            (f"{side}_arm", wr, o, Y, (0.016 * _R4,) * 2, (0.022 * _R4,) * 2),
            (f"{side}_hand", wr + 0.045 * d, o, Y, (0.012 * _R4,) * 2, (0.030 * _R4,) * 2),
            (f"{side}_hand", wr + 0.075 * d, o, Y, (0.010 * _R4,) * 2, (0.028 * _R4,) * 2),
            (f"{side}_hand", wr + 0.102 * d, o, Y, (0.006 * _R4,) * 2, (0.016 * _R4,) * 2),
        ]
        cage.branch(loop, (tilt, Y), frames, cap=f"{side}_hand")
    cage.points = [p * H for p in cage.points]
    return cage


def _cage_weights(spec: HumanSpec, cage: Cage) -> np.ndarray:
    """Weights (cage points, joints) from the inverse fourth power of the distance to each bone
    the point's part may follow; the feet are rigid (heel to ball on the ankle, toes on the toe
    joint: gait rolls them about the ball, blended weights in front of it would turn into the ground)."""
    P = rest_positions(spec)
    pts = np.array(cage.points)
    part = np.array(cage.point_part)
    dist = np.full((len(pts), len(JOINT_NAMES)), np.inf)
    for name, allowed in _PART_JOINTS.items():
        sel = part == name
        for j in allowed:
            end = P[_BONE_END[j]]
            if name == "torso" and j.endswith("_shoulder"):  # the torso follows the shoulder, not the arm hanging beside it
                end = P[j] + 0.15 * (end - P[j])
            dist[sel, JOINT_NAMES.index(j)] = _segment_distance(pts[sel], P[j], end)
    raw = np.where(np.isfinite(dist), 1.0 / np.maximum(dist, 0.01 * spec.height) ** 4, 0.0)
    for side in "lr":
        foot = part == f"{side}_foot"
        toe = pts[:, 1] >= P[f"{side}_toe"][1]
        raw[foot] = 0.0
        raw[foot & ~toe, JOINT_NAMES.index(f"{side}_ankle")] = 1.0
        raw[foot & toe, JOINT_NAMES.index(f"{side}_toe")] = 1.0
    return raw / raw.sum(axis=1, keepdims=True)


SUBDIVISIONS = 2  # Catmull-Clark steps from the cage: 16 quads per cage quad
STATIC_SUBDIVISIONS = 1  # static people, small in generated scenes and written with per-corner normals and uvs: 4
RIGID_FOOT = 0.035  # fraction of stature: the foot below this (below the ankle joint) is rigid


@functools.lru_cache(maxsize=64)
def _body(spec: HumanSpec, levels: int | None = None):
    """(points, quads, part per point, part per quad, weights (points, joints)) of the skin
    subdivided ``levels`` (default :data:`SUBDIVISIONS`) times, read-only."""
    cage = body_cage(spec)
    pts, quads, face_part, weights = cage.subdivide(_cage_weights(spec, cage), SUBDIVISIONS if levels is None else levels)
    P = rest_positions(spec)
    for side in "lr":  # subdivision blends the feet again: below the ankle they are rigid, hinged at the ball
        on = np.zeros(len(pts), bool)
        on[quads[face_part == f"{side}_foot"].ravel()] = True
        on &= pts[:, 2] < RIGID_FOOT * spec.height
        toe = pts[:, 1] >= P[f"{side}_toe"][1]
        weights[on] = 0.0
        weights[on & ~toe, JOINT_NAMES.index(f"{side}_ankle")] = 1.0
        weights[on & toe, JOINT_NAMES.index(f"{side}_toe")] = 1.0
    # Flat soles: the cage's soles reach below the ground, the subdivided surface is cut at z = 0.
    pts[:, 2] = np.maximum(pts[:, 2], 0.0)
    first = np.unique(quads.ravel(), return_index=True)[1] // 4
    out = (round_values(pts), quads, face_part[first], face_part, weights)
    for a in out:
        a.setflags(write=False)  # cached: shared by every caller
    return out


def body_mesh(spec: HumanSpec):
    """(points (N,3), faceVertexCounts, faceVertexIndices, part name per point) of the body: one
    closed, smooth quad mesh (the cage subdivided :data:`SUBDIVISIONS` times)."""
    pts, quads, parts, _, _ = _body(spec)
    return pts.copy(), np.full(len(quads), 4), quads.ravel().copy(), list(parts)



def foot_shape(spec: HumanSpec) -> tuple[float, float, float, float]:
    """(heel, ball, tip, ankle height) of the body's feet, metres: how far the back of the heel, the
    ball (toe joint) and the toe tip lie forward of the ankle, and the ankle above the sole; measured
    on the authored points skinned mostly to an ankle and its toe joint, as a character's are
    (lfusd.author.people), so the procedural human walks exactly as a character made of it."""
    P = rest_positions(spec)
    pts = body_mesh(spec)[0].astype(np.float32).astype(np.float64)
    ji, jw = skin_weights(spec)
    jw = jw.astype(np.float32).astype(np.float64)
    shapes = []
    for side in "lr":
        own = np.isin(ji, [JOINT_NAMES.index(f"{side}_ankle"), JOINT_NAMES.index(f"{side}_toe")])
        sel = (jw * own).sum(axis=1) >= 0.5
        a = P[f"{side}_ankle"]
        fwd = pts[sel, 1] - a[1]
        shapes.append((fwd.min(), P[f"{side}_toe"][1] - a[1], fwd.max(), a[2] - pts[sel, 2].min()))
    heel, ball, tip, height = np.array(shapes).T
    return float(heel.min()), float(ball.mean()), float(tip.max()), float(height.mean())

def face_regions(spec: HumanSpec, points: np.ndarray, counts, indices, parts: list[str]) -> np.ndarray:
    """The clothing region (an index into :data:`REGIONS`) of every face of ``body_mesh``."""
    look = appearance(spec)
    P = rest_positions(spec)
    H = spec.height
    counts, indices = np.asarray(counts), np.asarray(indices)
    starts = np.concatenate([[0], np.cumsum(counts)[:-1]])
    part = np.array(parts)[indices[starts]]
    centre = np.add.reduceat(points[indices], starts, axis=0) / counts[:, None]
    region = np.zeros(len(counts), int)  # skin
    region[part == "hair"] = REGIONS.index("hair")
    region[np.char.endswith(part, "_foot")] = REGIONS.index("shoes")
    torso = part == "torso"
    region[torso] = np.where(centre[torso, 2] < 0.53 * H, REGIONS.index("bottom"), REGIONS.index("top"))
    for side in "lr":
        arm = part == f"{side}_arm"
        sh, wr = P[f"{side}_shoulder"], P[f"{side}_wrist"]
        along = (centre[arm] - sh) @ (wr - sh) / float((wr - sh) @ (wr - sh))
        region[arm] = np.where(along < look["sleeves"], REGIONS.index("top"), 0)
        leg = part == f"{side}_leg"
        hip, ankle = P[f"{side}_hip"][2], P[f"{side}_ankle"][2]
        down = (hip - centre[leg, 2]) / (hip - ankle)
        region[leg] = np.where(down < look["legs"], REGIONS.index("bottom"), 0)
        region[leg & (centre[:, 2] < SHOE_TOP * H)] = REGIONS.index("shoes")
    return region


def body_regions(spec: HumanSpec) -> dict[str, tuple[np.ndarray, np.ndarray, np.ndarray]]:
    """A static (unskinned) person as closed meshes, {region: (points, counts, indices)}: the
    skin subdivided :data:`STATIC_SUBDIVISIONS` times, cut into its clothing regions (the scalp
    raised by the hair's thickness), each piece closed by fans across its rims inside the body."""
    pts, quads, parts, _, _ = _body(spec, STATIC_SUBDIVISIONS)
    region = face_regions(spec, pts, np.full(len(quads), 4), quads.ravel(), list(parts))
    hair = _scalp(spec, STATIC_SUBDIVISIONS)
    if hair is not None:
        sel, thick = hair
        region[sel] = REGIONS.index("hair")
        pts = pts.copy()
        on = np.zeros(len(pts), bool)
        on[quads[sel].ravel()] = True
        on[quads[~sel].ravel()] = False  # the hairline stays on the skin: the pieces meet
        pts[on] += _vertex_normals(pts, quads)[on] * thick[on, None]
    out = {}
    for k, name in enumerate(REGIONS):
        if np.any(region == k):
            out[name] = _closed_piece(pts, quads, region == k)
    return out


def _closed_piece(pts: np.ndarray, quads: np.ndarray, faces: np.ndarray):
    """The ``faces`` (a mask) of a closed, outward quad mesh as a closed mesh of their own: each
    loop of the piece's rim is closed by a fan of triangles to the loop's centre."""
    used, local = np.unique(quads[faces], return_inverse=True)
    local = local.reshape(-1, 4)
    edges = np.concatenate([local[:, [j, (j + 1) % 4]] for j in range(4)])
    _, inv, count = np.unique(np.sort(edges, axis=1), axis=0, return_inverse=True, return_counts=True)
    rim = edges[count[inv.ravel()] == 1]  # edges of one face of the piece
    points = list(pts[used])
    counts, indices = [4] * len(local), list(local.ravel())
    if len(rim):
        loop = np.arange(len(used))  # union-find over the rim's edges: one label per loop
        for a, b in rim.tolist():
            while loop[a] != a:
                a = loop[a]
            while loop[b] != b:
                b = loop[b]
            loop[max(a, b)] = min(a, b)
        for v in range(len(loop)):
            loop[v] = loop[loop[v]]  # parents have smaller indices: one pass resolves every root
        for label in np.unique(loop[rim[:, 0]]):
            mine = rim[loop[rim[:, 0]] == label]
            centre = len(points)
            points.append(pts[used][np.unique(mine)].mean(axis=0))
            for a, b in mine:  # the cap runs each rim edge the other way round
                counts.append(3)
                indices += [int(b), int(a), centre]
    return round_values(np.array(points)), np.array(counts), np.array(indices)


def _translation(p) -> Gf.Matrix4d:
    return Gf.Matrix4d(1.0).SetTranslate(Gf.Vec3d(*map(float, p)))


def rest_transforms(spec: HumanSpec) -> tuple[list[Gf.Matrix4d], list[Gf.Matrix4d]]:
    """(bind = skeleton-space rest, rest = parent-space rest) matrices, pure translations."""
    P = rest_positions(spec)
    bind = [_translation(P[n]) for n in JOINT_NAMES]
    rest = [_translation(P[n] - (P[_PARENT[n]] if _PARENT[n] else 0.0)) for n in JOINT_NAMES]
    return bind, rest


HAIR_NAME = "Hair"
HAIR_GAP = 0.001  # metres between the skin and the hair layer's inner side


def _vertex_normals(points: np.ndarray, quads: np.ndarray) -> np.ndarray:
    """Unit area-weighted normals of a closed, outward quad mesh (cross product of the diagonals)."""
    p = points[quads]
    face = np.cross(p[:, 2] - p[:, 0], p[:, 3] - p[:, 1])
    n = np.zeros_like(points)
    for k in range(4):
        np.add.at(n, quads[:, k], face)
    return n / np.linalg.norm(n, axis=1, keepdims=True)


def _scalp(spec: HumanSpec, levels: int | None = None):
    """(mask of the skin's faces under the hair, the hair's thickness at each skin point), or None
    for a bald look: the scalp down to a hairline over the forehead, above the ears and, for long
    hair, down the nape; 3 mm thick at the hairline to a few centimetres on the crown."""
    look = appearance(spec)
    if look["hair"] is None:
        return None
    H = spec.height
    pts, quads, _, face_part, _ = _body(spec, levels)
    rel = pts[quads].mean(axis=1) - [0.0, 0.0, 0.935 * H]
    across = np.hypot(rel[:, 0], rel[:, 1])
    elev = np.degrees(np.arctan2(rel[:, 2], across))
    front = rel[:, 1] / np.maximum(across, 1e-9)  # 1 facing forward, -1 at the back
    back = -(15.0 + 45.0 * look["hair_length"])
    line = np.where(front > 0, -5.0 + 40.0 * front, -5.0 + (5.0 + back) * -front)  # the hairline's elevation, degrees
    sel = np.isin(face_part, ["head", "neck"]) & (elev > line)
    vrel = pts - [0.0, 0.0, 0.935 * H]
    v_elev = np.degrees(np.arctan2(vrel[:, 2], np.hypot(vrel[:, 0], vrel[:, 1])))
    volume = (0.004 + 0.008 * look["hair_length"]) * H
    return sel, 0.003 + volume * np.clip((v_elev + 10.0) / 70.0, 0.0, 1.0) ** 2  # thin at the hairline, full on the crown


def hair_mesh(spec: HumanSpec, levels: int | None = None):
    """The hair: a closed shell over the scalp (and the nape, for long hair), its inner side
    :data:`HAIR_GAP` and its outer side 3 mm (at the hairline) to a few centimetres (on the crown)
    off the skin along the skin's normals, skinned with the weights of the skin beneath it, so it
    moves with the head and never enters it. (points, counts, indices, joint indices, weights), or
    None for a bald look."""
    scalp = _scalp(spec, levels)
    if scalp is None:
        return None
    sel, thick = scalp
    pts, quads, _, _, _ = _body(spec, levels)
    ji, jw = skin_weights(spec, levels=levels)
    points, shell, used = _shell(pts, quads, _vertex_normals(pts, quads), sel, HAIR_GAP, thick)
    return points, np.full(len(shell), 4), shell.ravel(), ji[used], jw[used]


def _shell(pts: np.ndarray, quads: np.ndarray, normals: np.ndarray, faces: np.ndarray, inner: float, outer: np.ndarray):
    """A closed layer over the ``faces`` (a mask) of a closed, outward quad mesh: its points moved
    ``inner`` and ``outer`` (per point) along ``normals``, joined along the patch's rim. Returns
    (points, quads, index of the mesh point under each layer point)."""
    used, local = np.unique(quads[faces], return_inverse=True)
    local = local.reshape(-1, 4)
    k = len(used)
    n = normals[used]
    points = np.concatenate([pts[used] + n * outer[used, None], pts[used] + n * inner])
    edges = np.concatenate([local[:, [j, (j + 1) % 4]] for j in range(4)])
    _, inv, count = np.unique(np.sort(edges, axis=1), axis=0, return_inverse=True, return_counts=True)
    rim = edges[count[inv.ravel()] == 1]  # edges of one face of the patch
    shell = np.concatenate([local, local[:, ::-1] + k, np.c_[rim[:, 1], rim[:, 0], rim[:, 0] + k, rim[:, 1] + k]])
    return round_values(points), shell, np.concatenate([used, used])


def _skinned_mesh(stage: Usd.Stage, path: Sdf.Path, skel: UsdSkel.Skeleton, points, counts, indices, ji, jw) -> UsdGeom.Mesh:
    mesh = UsdGeom.Mesh.Define(stage, path)
    mesh.CreatePointsAttr(Vt.Vec3fArray.FromNumpy(points.astype(np.float32)))
    mesh.CreateFaceVertexCountsAttr(Vt.IntArray.FromNumpy(counts.astype(np.int32)))
    mesh.CreateFaceVertexIndicesAttr(Vt.IntArray.FromNumpy(indices.astype(np.int32)))
    # No subdivision: Blender would add a Subdivision modifier and change the vertex set.
    mesh.CreateSubdivisionSchemeAttr(UsdGeom.Tokens.none)
    lo, hi = points.min(axis=0), points.max(axis=0)
    mesh.CreateExtentAttr(Vt.Vec3fArray([Gf.Vec3f(*map(float, lo)), Gf.Vec3f(*map(float, hi))]))
    binding = UsdSkel.BindingAPI.Apply(mesh.GetPrim())
    binding.CreateSkeletonRel().SetTargets([skel.GetPath()])
    binding.CreateJointIndicesPrimvar(False, ji.shape[1]).Set(Vt.IntArray.FromNumpy(ji.ravel().astype(np.int32)))
    binding.CreateJointWeightsPrimvar(False, jw.shape[1]).Set(Vt.FloatArray.FromNumpy(jw.ravel().astype(np.float32)))
    binding.CreateGeomBindTransformAttr(Gf.Matrix4d(1.0))
    return mesh


def define_human(stage: Usd.Stage, path: str | Sdf.Path, spec: HumanSpec = HumanSpec(), label: str = "person") -> UsdSkel.Root:
    """Author a skinned human at ``path``: SkelRoot (labelled) / Skeleton, Body mesh (clothes are
    materials on its face subsets) and, unless the look is bald, a Hair mesh skinned like the scalp.

    The skeleton is not yet animated; lfusd.author.gait writes a UsdSkel Animation and binds it.
    """
    spec.validate()
    path = Sdf.Path(str(path))
    root = UsdSkel.Root.Define(stage, path)
    set_class_label(root.GetPrim(), label)
    skel = UsdSkel.Skeleton.Define(stage, path.AppendChild(SKELETON_NAME))
    skel.CreateJointsAttr(Vt.TokenArray(joint_paths()))
    skel.CreateJointNamesAttr(Vt.TokenArray(JOINT_NAMES))
    bind, rest = rest_transforms(spec)
    skel.CreateBindTransformsAttr(Vt.Matrix4dArray(bind))
    skel.CreateRestTransformsAttr(Vt.Matrix4dArray(rest))
    skel.GetPurposeAttr().Set(UsdGeom.Tokens.guide)  # not drawn; the body is

    points, counts, indices, parts = body_mesh(spec)
    mesh = _skinned_mesh(stage, path.AppendChild(MESH_NAME), skel, points, counts, indices, *skin_weights(spec))
    look = appearance(spec)
    mesh.CreateDisplayColorPrimvar(UsdGeom.Tokens.constant).Set(Vt.Vec3fArray([Gf.Vec3f(*look["skin"])]))
    _dress(stage, path, mesh, spec, look, points, counts, indices, parts)
    hair = hair_mesh(spec)
    if hair is not None:
        layer = _skinned_mesh(stage, path.AppendChild(HAIR_NAME), skel, *hair)
        layer.CreateDisplayColorPrimvar(UsdGeom.Tokens.constant).Set(Vt.Vec3fArray([Gf.Vec3f(*look["hair"])]))
        UsdShade.MaterialBindingAPI.Apply(layer.GetPrim()).Bind(_material(stage, path, "hair", look))
    return root


_ROUGHNESS = {"skin": 0.5, "hair": 0.6, "top": 0.85, "bottom": 0.8, "shoes": 0.4}


def _dress(stage: Usd.Stage, path: Sdf.Path, mesh: UsdGeom.Mesh, spec: HumanSpec, look: dict, points, counts, indices, parts) -> None:
    """Bind a UsdPreviewSurface per clothing region to a face subset of the body mesh
    (``<path>/Looks/<region>``; the subsets partition the faces)."""
    region = face_regions(spec, points, counts, indices, parts)
    binding = UsdShade.MaterialBindingAPI.Apply(mesh.GetPrim())
    for k, name in enumerate(REGIONS):
        faces = np.nonzero(region == k)[0]
        if not len(faces):
            continue
        subset = binding.CreateMaterialBindSubset(name, Vt.IntArray.FromNumpy(faces.astype(np.int32)), UsdGeom.Tokens.face)
        UsdShade.MaterialBindingAPI.Apply(subset.GetPrim()).Bind(_material(stage, path, name, look))
    binding.SetMaterialBindSubsetsFamilyType(UsdGeom.Tokens.partition)


def _material(stage: Usd.Stage, path: Sdf.Path, name: str, look: dict) -> UsdShade.Material:
    """The UsdPreviewSurface of region ``name`` at ``<path>/Looks/<name>``."""
    mat_path = path.AppendChild("Looks").AppendChild(name)
    mat = UsdShade.Material.Define(stage, mat_path)
    shader = UsdShade.Shader.Define(stage, mat_path.AppendChild("Surface"))
    shader.CreateIdAttr("UsdPreviewSurface")
    shader.CreateInput("diffuseColor", Sdf.ValueTypeNames.Color3f).Set(Gf.Vec3f(*look[name]))
    shader.CreateInput("roughness", Sdf.ValueTypeNames.Float).Set(_ROUGHNESS[name])
    mat.CreateSurfaceOutput().ConnectToSource(shader.ConnectableAPI(), "surface")
    return mat

"""A procedural human as UsdSkel: a skinned body mesh on a 19-joint skeleton, labelled ``person``.

The character frame is Z up, facing +Y, metres, with the origin on the ground between the feet
(so the character's right is +X). Joint rest orientations are the identity: every joint's
rest transform is a pure translation, which keeps animation maths simple and any retargeting
(see lfusd.author.gait) exact.

Proportions follow standard anthropometric fractions of stature (Drillis & Contini); ``build``
in [0, 1] widens the body (0 slim, 0.5 average, 1 heavy). ``look`` seeds the rest of a person's
appearance: hip, waist and chest girth, hair, skin tone and clothes (a top with long, short or no
sleeves, trousers or shorts, shoes), authored as UsdPreviewSurface materials bound to face subsets
of the one skinned mesh. Joints depend on stature alone, so every gait fits every look.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from pxr import Gf, Sdf, Usd, UsdGeom, UsdShade, UsdSkel, Vt

from ..errors import LfusdError
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


def _ring(center, axis, ref, a, b, n, power=2.0):
    """n points of a superellipse (half-axes a along ref, b along axis x ref) around ``center``."""
    axis = axis / np.linalg.norm(axis)
    u = ref - axis * np.dot(ref, axis)
    u /= np.linalg.norm(u)
    v = np.cross(axis, u)
    t = np.linspace(0.0, 2 * np.pi, n, endpoint=False)
    c, s = np.cos(t), np.sin(t)
    # Superellipse: |x/a|^p + |y/b|^p = 1 (p = 2 is an ellipse, larger is boxier).
    x = a * np.sign(c) * np.abs(c) ** (2.0 / power)
    y = b * np.sign(s) * np.abs(s) ** (2.0 / power)
    return center + np.outer(x, u) + np.outer(y, v)


class _MeshBuilder:
    def __init__(self):
        self.points: list[np.ndarray] = []
        self.parts: list[str] = []
        self.counts: list[int] = []
        self.indices: list[int] = []
        self.n = 0

    def tube(self, part: str, rings: list[np.ndarray], caps=(True, True)):
        """Loft closed rings (each (k,3), same k) into a tube, closed by fan caps."""
        k = len(rings[0])
        base = self.n
        for r in rings:
            self.points.append(r)
        self.parts += [part] * (k * len(rings))
        self.n += k * len(rings)
        for i in range(len(rings) - 1):
            for j in range(k):
                a, b = base + i * k + j, base + i * k + (j + 1) % k
                c, d = b + k, a + k
                self.counts.append(4)
                self.indices += [a, b, c, d]  # outward for counter-clockwise rings along the axis
        for end, cap in zip((0, len(rings) - 1), caps):
            if not cap:
                continue
            centre = rings[end].mean(axis=0)
            ci = self.n
            self.points.append(centre[None])
            self.parts.append(part)
            self.n += 1
            r0 = base + end * k
            for j in range(k):
                a, b = r0 + j, r0 + (j + 1) % k
                self.counts.append(3)
                self.indices += [ci, b, a] if end == 0 else [ci, a, b]

    def arrays(self):
        return np.concatenate(self.points), np.array(self.counts), np.array(self.indices), self.parts


def _profile_tube(mb, part, start, end, ref, sections, n, power=2.0):
    """A tube from ``start`` to ``end``; sections = [(t, a, b), ...] with t in [0, 1] along it."""
    axis = end - start
    rings = [_ring(start + t * axis, axis, ref, a, b, n, power) for t, a, b in sections]
    mb.tube(part, rings)


def body_mesh(spec: HumanSpec, segments: int = 16):
    """(points (N,3), faceVertexCounts, faceVertexIndices, part name per point) of the body."""
    H = spec.height
    w = 0.8 + 0.5 * spec.build  # girth factor
    look = appearance(spec)
    P = rest_positions(spec)
    mb = _MeshBuilder()
    X, Y, Z = np.eye(3)
    # Torso: crotch to the base of the neck, elliptical sections (half-width along X, half-depth along Y).
    torso = [
        (0.47, 0.075, 0.050), (0.50, 0.095, 0.060), (0.54, 0.100, 0.062), (0.58, 0.092, 0.058),
        (0.62, 0.082, 0.054), (0.66, 0.084, 0.056), (0.70, 0.092, 0.062), (0.74, 0.098, 0.064),
        (0.78, 0.104, 0.060), (0.81, 0.098, 0.050), (0.83, 0.060, 0.040), (0.845, 0.035, 0.032),
    ]
    # The look's girth factors: hips (up to 0.58 H), waist (0.6-0.68 H, deeper with a belly), chest.
    girth = [look["hips"]] * 4 + [look["waist"]] * 2 + [look["chest"]] * 4 + [1.0, 1.0]
    belly = [1.0] * 4 + [look["belly"]] * 2 + [1.0] * 6
    rings = [_ring(np.array([0.0, -0.005 * H, z * H]), Z, X, a * H * w * g, b * H * w * g * e, segments, 2.4)
             for (z, a, b), g, e in zip(torso, girth, belly)]
    mb.tube("torso", rings)
    # Neck and head.
    _profile_tube(mb, "neck", P["neck"] - [0, 0, 0.02 * H], P["head"] + [0, 0, 0.02 * H], Y,
                  [(0.0, 0.032 * H, 0.034 * H), (1.0, 0.03 * H, 0.032 * H)], segments)
    hc = np.array([0.0, 0.008 * H, H - 0.985 * 0.065 * H])  # crown at the stature
    head_rings = []
    for lat in np.radians(np.linspace(-80, 80, 9)):
        head_rings.append(_ring(hc + [0, 0, 0.065 * H * np.sin(lat)], Z, X, 0.05 * H * np.cos(lat),
                                0.06 * H * np.cos(lat), segments))
    mb.tube("head", head_rings)
    # Hair: a cap over the crown and the back of the head, 2-9 mm proud of it, its top at the stature.
    if look["hair"] is not None:
        length = look["hair_length"]
        hair_rings = []
        for lat in np.radians(np.linspace(-20 - 50 * length, 78, 7)):
            c = hc + [0, -0.006 * H, 0.068 * H * np.sin(lat)]
            hair_rings.append(_ring(c, Z, X, 0.055 * H * np.cos(lat), 0.062 * H * np.cos(lat), segments))
        mb.tube("hair", hair_rings)
    for side in "lr":
        s = -1.0 if side == "l" else 1.0
        # Leg: from above the hip joint (inside the torso) to just above the ankle.
        top = P[f"{side}_hip"] + [s * 0.006 * H, 0, 0.03 * H]
        bottom = P[f"{side}_ankle"] + [0, 0, 0.005 * H]
        kt = (top[2] - P[f"{side}_knee"][2]) / (top[2] - bottom[2])
        _profile_tube(mb, f"{side}_leg", top, bottom, Y, [
            (0.0, 0.058 * H * w, 0.058 * H * w), (0.12, 0.056 * H * w, 0.056 * H * w),
            (0.3, 0.048 * H * w, 0.048 * H * w), (kt - 0.06, 0.036 * H * w, 0.036 * H * w),
            (kt, 0.033 * H * w, 0.035 * H * w), (kt + 0.08, 0.036 * H * w, 0.038 * H * w),
            (kt + 0.2, 0.036 * H * w, 0.040 * H * w), (kt + 0.4, 0.026 * H * w, 0.028 * H * w),
            (1.0, 0.02 * H, 0.022 * H),
        ], segments)
        # Foot: a flat-soled box-like tube from heel to toe tip, sole at z = 0.
        heel = np.array([P[f"{side}_ankle"][0], -0.03 * H, 0.0])
        tip = P[f"{side}_toe_tip"] * [1, 1, 0]
        sections = [(0.0, 0.018, 0.02), (0.12, 0.024, 0.03), (0.4, 0.027, 0.026), (0.7, 0.03, 0.016), (1.0, 0.022, 0.01)]
        rings = []
        for t, a, hgt in sections:
            c = heel + t * (tip - heel) + [0, 0, hgt * H]
            rings.append(_ring(c, Y, X, a * H, hgt * H, segments, 4.0))
        mb.tube(f"{side}_foot", rings)
        # Arm: shoulder to wrist, then a flattened hand.
        sh, el, wr, ht = (P[f"{side}_{k}"] for k in ("shoulder", "elbow", "wrist", "hand_tip"))
        ta = np.linalg.norm(el - sh) / np.linalg.norm(wr - sh)
        start = sh + [0, 0, 0.02 * H]
        _profile_tube(mb, f"{side}_arm", start, wr, Y, [
            (0.0, 0.03 * H * w, 0.03 * H * w), (0.15, 0.032 * H * w, 0.032 * H * w),
            (ta - 0.05, 0.025 * H * w, 0.025 * H * w), (ta + 0.05, 0.024 * H * w, 0.024 * H * w),
            (ta + 0.25, 0.025 * H * w, 0.023 * H * w), (1.0, 0.018 * H, 0.015 * H),
        ], segments)
        _profile_tube(mb, f"{side}_hand", wr, ht, Y, [
            (0.0, 0.013 * H, 0.02 * H), (0.4, 0.012 * H, 0.027 * H), (1.0, 0.007 * H, 0.015 * H)], segments)
    return mb.arrays()


# Which joints may influence each part (keeps, e.g., hands from following the hips).
_PART_JOINTS = {
    "torso": ["pelvis", "spine", "chest", "neck", "l_shoulder", "r_shoulder", "l_hip", "r_hip"],
    "neck": ["chest", "neck", "head"],
    "head": ["neck", "head"],
    "hair": ["head"],
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


def _edges(counts: np.ndarray, indices: np.ndarray) -> np.ndarray:
    starts = np.concatenate([[0], np.cumsum(counts)[:-1]])
    pairs = []
    for k in range(int(counts.max())):
        sel = k < counts
        a = indices[starts[sel] + k]
        b = indices[starts[sel] + (k + 1) % counts[sel]]
        pairs.append(np.stack([a, b], axis=1))
    pairs = np.concatenate(pairs)
    return np.unique(np.sort(pairs, axis=1), axis=0)


HIP_ZONE = (0.41, 0.56)  # heights (fractions of stature) where torso and thighs share one weight field


def skin_weights(spec: HumanSpec, points: np.ndarray, parts: list[str], counts: np.ndarray | None = None,
                 indices: np.ndarray | None = None, influences: int = 4, smoothing: int = 4):
    """Smooth weights: inverse fourth power of the distance to each allowed bone, then
    ``smoothing`` rounds of averaging over mesh edges (when the faces are given), top ``influences``.

    Returns (joint indices (N, k) int, weights (N, k) float summing to 1).
    """
    P = rest_positions(spec)
    n = len(points)
    dist = np.full((n, len(JOINT_NAMES)), np.inf)
    parts_arr = np.array(parts)
    for part, allowed in _PART_JOINTS.items():
        sel = parts_arr == part
        if not sel.any():
            continue
        for name in allowed:
            j = JOINT_NAMES.index(name)
            dist[sel, j] = _segment_distance(points[sel], P[name], P[_BONE_END[name]])
    floor = 0.01 * spec.height  # avoids infinite weights for points on a bone
    raw = np.where(np.isfinite(dist), 1.0 / np.maximum(dist, floor) ** 4, 0.0)
    raw /= raw.sum(axis=1, keepdims=True)
    if counts is not None and indices is not None and smoothing:
        # Averaging over edges (parts are separate shells, so weights never leak between parts).
        e = _edges(np.asarray(counts), np.asarray(indices))
        deg = np.bincount(e.ravel(), minlength=n).astype(float)
        for _ in range(smoothing):
            acc = raw.copy()
            np.add.at(acc, e[:, 0], raw[e[:, 1]])
            np.add.at(acc, e[:, 1], raw[e[:, 0]])
            raw = acc / (1.0 + deg)[:, None]
    # Hips: the torso's bottom and the thighs' tops overlap (the legs start inside the torso). Both
    # take one weight field of position throughout HIP_ZONE (pelvis, spine and hip bones, soft and
    # unsmoothed), ramped out above it on the torso and below it on the legs, so where the two
    # surfaces meet they deform alike and never pass through each other (a thigh through the
    # pelvis is two surfaces moving differently in one place: ground truth there is a tie).
    hips = np.isin(parts_arr, ["torso", "l_leg", "r_leg"])
    if hips.any():
        H = spec.height
        field = np.zeros((int(hips.sum()), len(JOINT_NAMES)))
        for name in ("pelvis", "spine", "l_hip", "r_hip"):
            d = _segment_distance(points[hips], P[name], P[_BONE_END[name]])
            field[:, JOINT_NAMES.index(name)] = 1.0 / np.maximum(d, 0.06 * H) ** 2  # soft: the legs' top caps straddle bones
        field /= field.sum(axis=1, keepdims=True)
        z = points[hips, 2] / H
        lo, hi = HIP_ZONE
        ramp = np.where(parts_arr[hips] == "torso", np.clip((hi + 0.14 - z) / 0.14, 0, 1), np.clip((z - (lo - 0.16)) / 0.16, 0, 1))
        raw[hips] = (1 - ramp[:, None]) * raw[hips] + ramp[:, None] * field
    # Feet are two rigid pieces hinged at the ball (gait rolls them about it): blended weights
    # in front of the hinge would turn down into the ground at push-off.
    feet = np.char.endswith(parts_arr, "_foot")
    raw[feet] = np.eye(raw.shape[1])[np.argmax(raw[feet], axis=1)]
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
    return region


def body_regions(spec: HumanSpec, whole_parts: bool = False, segments: int = 16) -> dict[str, tuple[np.ndarray, np.ndarray, np.ndarray]]:
    """The body split by clothing region: {region: (points, counts, indices)}, each re-indexed.
    ``whole_parts``: every body part goes wholly to one region (arms to the top, legs to the
    bottom), so each region is a union of closed tubes (for static, unskinned people)."""
    points, counts, indices, parts = body_mesh(spec, segments)
    if whole_parts:
        starts = np.concatenate([[0], np.cumsum(counts)[:-1]])
        part = np.array(parts)[indices[starts]]
        by_part = {"hair": "hair", "torso": "top", "l_arm": "top", "r_arm": "top", "l_leg": "bottom", "r_leg": "bottom",
                   "l_foot": "shoes", "r_foot": "shoes"}
        region = np.array([REGIONS.index(by_part.get(p, "skin")) for p in part])
    else:
        region = face_regions(spec, points, counts, indices, parts)
    starts = np.concatenate([[0], np.cumsum(counts)[:-1]])
    out = {}
    for k, name in enumerate(REGIONS):
        faces = np.nonzero(region == k)[0]
        if not len(faces):
            continue
        idx = np.concatenate([indices[starts[f]:starts[f] + counts[f]] for f in faces])
        used, local = np.unique(idx, return_inverse=True)
        out[name] = (points[used], counts[faces], local)
    return out


def _translation(p) -> Gf.Matrix4d:
    return Gf.Matrix4d(1.0).SetTranslate(Gf.Vec3d(*map(float, p)))


def rest_transforms(spec: HumanSpec) -> tuple[list[Gf.Matrix4d], list[Gf.Matrix4d]]:
    """(bind = skeleton-space rest, rest = parent-space rest) matrices, pure translations."""
    P = rest_positions(spec)
    bind = [_translation(P[n]) for n in JOINT_NAMES]
    rest = [_translation(P[n] - (P[_PARENT[n]] if _PARENT[n] else 0.0)) for n in JOINT_NAMES]
    return bind, rest


def define_human(stage: Usd.Stage, path: str | Sdf.Path, spec: HumanSpec = HumanSpec(), label: str = "person") -> UsdSkel.Root:
    """Author a skinned human at ``path``: SkelRoot (labelled) / Skeleton, Body mesh.

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
    mesh = UsdGeom.Mesh.Define(stage, path.AppendChild(MESH_NAME))
    mesh.CreatePointsAttr(Vt.Vec3fArray.FromNumpy(points.astype(np.float32)))
    mesh.CreateFaceVertexCountsAttr(Vt.IntArray.FromNumpy(counts.astype(np.int32)))
    mesh.CreateFaceVertexIndicesAttr(Vt.IntArray.FromNumpy(indices.astype(np.int32)))
    # No subdivision: Blender would add a Subdivision modifier and change the vertex set.
    mesh.CreateSubdivisionSchemeAttr(UsdGeom.Tokens.none)
    lo, hi = points.min(axis=0), points.max(axis=0)
    mesh.CreateExtentAttr(Vt.Vec3fArray([Gf.Vec3f(*map(float, lo)), Gf.Vec3f(*map(float, hi))]))
    look = appearance(spec)
    mesh.CreateDisplayColorPrimvar(UsdGeom.Tokens.constant).Set(Vt.Vec3fArray([Gf.Vec3f(*look["skin"])]))
    _dress(stage, path, mesh, spec, look, points, counts, indices, parts)
    ji, jw = skin_weights(spec, points, parts, counts, indices)
    binding = UsdSkel.BindingAPI.Apply(mesh.GetPrim())
    binding.CreateSkeletonRel().SetTargets([skel.GetPath()])
    binding.CreateJointIndicesPrimvar(False, ji.shape[1]).Set(Vt.IntArray.FromNumpy(ji.ravel().astype(np.int32)))
    binding.CreateJointWeightsPrimvar(False, jw.shape[1]).Set(Vt.FloatArray.FromNumpy(jw.ravel().astype(np.float32)))
    binding.CreateGeomBindTransformAttr(Gf.Matrix4d(1.0))
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
        mat_path = path.AppendChild("Looks").AppendChild(name)
        mat = UsdShade.Material.Define(stage, mat_path)
        shader = UsdShade.Shader.Define(stage, mat_path.AppendChild("Surface"))
        shader.CreateIdAttr("UsdPreviewSurface")
        shader.CreateInput("diffuseColor", Sdf.ValueTypeNames.Color3f).Set(Gf.Vec3f(*look[name]))
        shader.CreateInput("roughness", Sdf.ValueTypeNames.Float).Set(_ROUGHNESS[name])
        mat.CreateSurfaceOutput().ConnectToSource(shader.ConnectableAPI(), "surface")
        subset = binding.CreateMaterialBindSubset(name, Vt.IntArray.FromNumpy(faces.astype(np.int32)), UsdGeom.Tokens.face)
        UsdShade.MaterialBindingAPI.Apply(subset.GetPrim()).Bind(mat)
    binding.SetMaterialBindSubsetsFamilyType(UsdGeom.Tokens.partition)

"""Recognising a character's joints: by the skeleton's shape (:func:`recognise_biped`), and by
name through lfusd's joint alias table (:func:`recognise_roles`, the fallback).

lfusd drives any UsdSkel skeleton through a few *roles* (pelvis, spine, chest, neck, head and,
per side, shoulder, elbow, wrist, hip, knee, ankle, toe). A joint's name is matched to a role
like this (docs/CONVENTIONS.md, "Characters"):

1. take the leaf of the joint path (``Hips/Spine/Neck`` -> ``Neck``) and drop any namespace
   prefix up to the last ``:`` (``mixamorig:LeftUpLeg`` -> ``LeftUpLeg``);
2. split it into words at separators (``_ . - space``), camelCase and digits; a word ``left``,
   ``l``, ``right`` or ``r`` (or a leading/trailing ``left``/``right`` in one lower-case word)
   gives the side and is removed;
3. join the rest in lower case (``upleg``, ``spine01``); when that is not in the table, drop
   leading words until it is (``mixamorig_LeftUpLeg``, ``Bip01 L Thigh``, ``DEF-thigh.L``);
4. each role takes the first alias of its list (best first) that some joint of its side has and
   that no other role took.

So Mixamo (``mixamorig:Hips``, ``mixamorig_LeftUpLeg``), glTF/Blender (``Hips``, ``LeftUpLeg``,
``LeftLeg``, ``LeftFoot``, ``LeftArm``, ``LeftForeArm``, ``Spine``, ``Head``), Unreal
(``pelvis``, ``thigh_l``, ``calf_l``, ``foot_l``, ``ball_l``, ``upperarm_l``), SMPL
(``pelvis``, ``left_hip``, ``left_knee``, ``left_ankle``, ``left_foot`` = toe, ``spine1``) and
lfusd's own names (``l_hip``, ``l_knee``, ...) all work. The order inside a list settles names
that mean different joints in different rigs: SMPL's ``left_foot`` is a toe (its ankle is
``left_ankle``) while Mixamo's ``LeftFoot`` is the ankle; Mixamo's ``LeftShoulder`` is a clavicle
(its upper arm is ``LeftArm``) while SMPL's ``left_shoulder`` is the upper arm.
"""

from __future__ import annotations

import re

import numpy as np

ROLES = ("pelvis", "spine", "chest", "neck", "head") + tuple(
    f"{s}_{j}" for s in "lr" for j in ("shoulder", "elbow", "wrist", "hip", "knee", "ankle", "toe")
)
#: Roles the gait needs: without them a character cannot walk.
REQUIRED_ROLES = ("pelvis", "l_hip", "l_knee", "l_ankle", "r_hip", "r_knee", "r_ankle")

#: The alias table: role (per-side roles without their ``l_``/``r_``) -> normalised joint names,
#: best first (see the module docstring for the normalisation).
ALIASES: dict[str, tuple[str, ...]] = {
    "pelvis": ("pelvis", "hips", "hip"),
    "spine": ("spine", "spine1", "spine01", "spine001", "abdomen", "lowerback", "torso"),
    "chest": ("chest", "spine2", "spine02", "spine002", "upperchest", "thorax", "spine3", "spine03"),
    "neck": ("neck", "neck1", "neck01"),
    "head": ("head",),
    "shoulder": ("upperarm", "arm", "humerus", "shoulder"),
    "elbow": ("forearm", "lowerarm", "elbow"),
    "wrist": ("wrist", "hand"),
    "hip": ("upleg", "thigh", "upperleg", "femur", "hip"),
    "knee": ("leg", "calf", "shin", "lowerleg", "knee"),
    "ankle": ("ankle", "foot"),
    "toe": ("toebase", "toe", "toes", "ball", "foot"),
}
_KNOWN = {a for names in ALIASES.values() for a in names}
_SIDE_WORDS = {"l": "l", "left": "l", "r": "r", "right": "r"}
_WORD = re.compile(r"[A-Z]+(?=[A-Z][a-z])|[A-Z]?[a-z]+|[A-Z]+|\d+")


def normalise(joint: str) -> tuple[str, str]:
    """(side 'l', 'r' or '', normalised base name) of a UsdSkel joint path (see the module doc)."""
    leaf = joint.split("/")[-1].split(":")[-1]
    words = _WORD.findall(leaf)
    side = ""
    kept = []
    for w in words:
        s = _SIDE_WORDS.get(w.lower())
        if s and not side:
            side = s
        else:
            kept.append(w.lower())
    if not side and kept:  # one lower-case word such as 'leftupleg' or 'thighright'
        for word, s in (("left", "l"), ("right", "r")):
            if kept[0].startswith(word) and len(kept[0]) > len(word):
                kept[0], side = kept[0][len(word):], s
                break
            if kept[-1].endswith(word) and len(kept[-1]) > len(word):
                kept[-1], side = kept[-1][: -len(word)], s
                break
    for i in range(len(kept)):
        base = "".join(kept[i:])
        if base in _KNOWN:
            return side, base
    return side, "".join(kept)


def recognise_roles(joints: list[str]) -> dict[str, int]:
    """Map roles (pelvis, l_hip, ...) to joint indices by the alias table."""
    by_name: dict[tuple[str, str], int] = {}
    for i, j in enumerate(joints):
        by_name.setdefault(normalise(j), i)
    roles: dict[str, int] = {}
    taken: set[int] = set()
    for role in ROLES:
        side, base = (role[0], role[2:]) if role[1] == "_" else ("", role)
        for alias in ALIASES[base]:
            i = by_name.get((side, alias))
            if i is not None and i not in taken:
                roles[role] = i
                taken.add(i)
                break
    return roles


def expected_names(role: str) -> str:
    """A few accepted names of ``role`` for error messages ('LeftUpLeg/l_hip/thigh_l')."""
    examples = {
        "pelvis": "Hips/pelvis", "spine": "Spine/spine1", "chest": "Spine2/chest", "neck": "Neck", "head": "Head",
        "shoulder": "{L}Arm/{l}_shoulder/upperarm_{l}", "elbow": "{L}ForeArm/{l}_elbow/lowerarm_{l}",
        "wrist": "{L}Hand/{l}_wrist/hand_{l}", "hip": "{L}UpLeg/{l}_hip/thigh_{l}",
        "knee": "{L}Leg/{l}_knee/calf_{l}", "ankle": "{L}Foot/{l}_ankle/foot_{l}", "toe": "{L}ToeBase/{l}_toe/ball_{l}",
    }
    if role[1:2] == "_":
        side = role[0]
        return examples[role[2:]].format(L="Left" if side == "l" else "Right", l=side)
    return examples[role]


# ---------------------------------------------------------------------------------------------
# Recognising a biped by its skeleton's shape: topology and rest pose, names only as hints.

# Fractions of the skeleton's joint height range (lowest to highest joint).
_FOOT_BAND = 0.2  # feet: joints this close to the lowest joint ...
_LEG_RISE = 0.35  # ... that hang below a joint at least this high (an Unreal 'root' on the ground does not)
_ANKLE_BAND = 0.12  # an ankle lies this close to the lowest joint (a split shin's mid joint does not)
_HIP_REACH = 0.9  # a hip lies at least this fraction of the leg's longest reach above its ankle
_LONG_BONE = 0.6  # a limb's long bones (thigh, shin; upper arm, forearm): this fraction of its longest or more
_ARM_REACH = 0.08  # an arm reaches this far sideways from the spine (hands hang ~0.12 out in an A-pose)
_SHOULDER_OUT = 0.06  # a shoulder lies this far sideways from the spine (a human's ~0.1, a clavicle's root ~0.03)


class NotABiped(ValueError):
    """The skeleton has no recognisable pelvis, spine and two legs; the message says what is missing."""


def _ancestors(j: int, parents) -> list[int]:
    """``j`` and its ancestors, ``j`` first."""
    out = [j]
    while parents[out[-1]] >= 0:
        out.append(int(parents[out[-1]]))
    return out


def _lca(joints, parents) -> int:
    chains = [_ancestors(j, parents)[::-1] for j in joints]
    common = -1
    for level in zip(*chains):
        if len(set(level)) != 1:
            break
        common = level[0]
    return common


def _path(top: int, bottom: int, parents) -> list[int]:
    """Joints from ``top`` (excluded) down to ``bottom`` (included); ``top`` must be an ancestor."""
    chain = _ancestors(bottom, parents)
    return chain[: chain.index(top)][::-1]


def _long_bones(chain: list[int], pos: np.ndarray) -> list[tuple[int, int]]:
    """(start, end) joints of a limb's long bones along ``chain``, its joints from where it leaves
    the body: bones between two of the limb's joints (the offset from the body to the limb's first
    joint is none), short ones (a clavicle, a hip offset joint, twist joints, the hand) skipped."""
    joints = chain
    lengths = np.array([np.linalg.norm(pos[b] - pos[a]) for a, b in zip(joints, joints[1:])])
    if not len(lengths) or lengths.max() <= 0:
        return []
    long = lengths >= _LONG_BONE * lengths.max()
    return [(joints[i], joints[i + 1]) for i in np.nonzero(long)[0]]


def recognise_biped(joints: list[str], parents, pos) -> dict[str, int]:
    """Map roles (pelvis, l_hip, ...) to joint indices from the skeleton's shape.

    ``pos``: rest (bind) joint positions, (J, 3), in a frame whose +Z is the character's up
    (any units, any facing). Feet are the two lowest joint chains hanging from the body; the
    pelvis is where the legs and the spine (towards the highest joint) meet; a leg's ankle is its
    first joint near the ground, its hip the lowest of its own joints about a leg's length above,
    its knee the joint between them nearest the middle; toes are the foot's forward branch;
    the chest is where the two arms leave the spine, and the upper arm, forearm and wrist
    follow from the arms' long bones (an arm without two: its first joints in order). Left is the side to the left of where the toes point;
    without toe joints, the side that joint names give (``L``/``left`` words). Raises
    :class:`NotABiped` naming what is missing."""
    pos = np.asarray(pos, np.float64)
    parents = np.asarray(parents)
    n = len(joints)
    if n < 7:
        raise NotABiped(f"it has {n} joints, fewer than a pelvis and two legs of hip, knee and ankle need")
    z = pos[:, 2]
    lo, hi = float(z.min()), float(z.max())
    span = hi - lo
    if span <= 0:
        raise NotABiped("all its joints are at one height")
    top = int(np.argmax(z))
    lows = [j for j in range(n) if z[j] < lo + _FOOT_BAND * span
            and any(z[a] > lo + _LEG_RISE * span for a in _ancestors(j, parents)[1:])]
    if not lows:
        raise NotABiped("no joint chain hangs down to its lowest joints (no legs)")
    branch = _lca(lows, parents)
    if branch < 0:
        raise NotABiped("its lowest joints belong to separate joint trees")
    kids = {}
    for j in lows:
        if j == branch:
            continue
        kid = _path(branch, j, parents)[0]
        kids.setdefault(kid, []).append(j)
    if len(kids) != 2:
        raise NotABiped(f"{len(kids)} joint chains reach the ground where a biped has 2 legs")
    feet = [min(js, key=lambda j: z[j]) for js in kids.values()]
    pelvis = _lca([*feet, top], parents)
    if pelvis < 0 or pelvis in feet or pelvis == top:
        raise NotABiped("its legs and its spine do not meet at a pelvis joint")
    roles: dict[str, int] = {"pelvis": pelvis}
    legs = []
    for foot, other in zip(feet, feet[::-1]):
        # The ankle: the leg's first joint near the ground. The hip: the lowest of the leg's own
        # joints (not shared with the other leg) about a leg's length above the ankle (below hip
        # offset joints such as CMU's LHipJoint). The knee: the joint between them nearest the
        # middle (rigs that split thigh and shin into two bones each have joints at 1/4 and 3/4).
        chain = _path(pelvis, foot, parents)
        near_ground = [j for j in chain if z[j] < lo + _ANKLE_BAND * span]
        ankle = near_ground[0] if near_ground else foot
        shared = set(_ancestors(other, parents))
        upper = [j for j in chain[: chain.index(ankle)] if j not in shared]
        reach = [float(np.linalg.norm(pos[j] - pos[ankle])) for j in upper]
        hip = [j for j, r in zip(upper, reach) if r >= _HIP_REACH * max(reach)][-1] if upper else None
        between = upper[upper.index(hip) + 1:] if hip is not None else []
        if not between:
            raise NotABiped(f"its leg down to joint {joints[foot]} has no hip, knee and ankle joints")
        knee = min(between, key=lambda j: abs(np.linalg.norm(pos[j] - pos[hip]) - np.linalg.norm(pos[ankle] - pos[j])))
        down = [pos[knee] - pos[hip], pos[ankle] - pos[knee]]
        if any(d[2] > -0.5 * np.linalg.norm(d) for d in down) or z[ankle] > lo + _ANKLE_BAND * span:
            raise NotABiped(f"its leg down to joint {joints[foot]} does not hang down from the pelvis to an ankle")
        # Toes: the child of the ankle leading furthest forward-and-sideways (a heel joint is shorter).
        below = [j for j in range(n) if j != ankle and ankle in _ancestors(j, parents)]
        toe = None
        if below:
            far = max(below, key=lambda j: np.linalg.norm(pos[j, :2] - pos[ankle, :2]))
            if np.linalg.norm(pos[far, :2] - pos[ankle, :2]) > 0.03 * span:
                toe = _path(ankle, far, parents)[0]
        legs.append({"hip": hip, "knee": knee, "ankle": ankle, "toe": toe, "chain": chain})
    # Which leg is the left one: the toes point forward, and left is up x forward.
    toes = [leg["toe"] for leg in legs if leg["toe"] is not None]
    side = None
    if len(toes) == 2:
        fwd = sum(pos[leg["toe"], :2] - pos[leg["ankle"], :2] for leg in legs)
        across = pos[legs[0]["ankle"], :2] - pos[legs[1]["ankle"], :2]
        left = np.array([-fwd[1], fwd[0]])
        if np.linalg.norm(fwd) > 0 and abs(across @ left) > 0.2 * np.linalg.norm(across) * np.linalg.norm(left):
            side = "l" if across @ left > 0 else "r"
    if side is None:
        hints = [{normalise(joints[j])[0] for j in leg["chain"]} - {""} for leg in legs]
        if len(hints[0]) == 1 and len(hints[1]) == 1 and hints[0] != hints[1]:
            side = next(iter(hints[0]))
    if side is None:
        raise NotABiped("its feet have no toe joints and its leg joints no left/right names, so its front is unknown")
    if side == "r":
        legs.reverse()
    for s, leg in zip("lr", legs):
        for role in ("hip", "knee", "ankle", "toe"):
            if leg[role] is not None:
                roles[f"{s}_{role}"] = leg[role]
    # The spine: pelvis to the highest joint; arms branch off it sideways.
    spine = _path(pelvis, top, parents)
    on_spine = set(spine) | {pelvis}
    left_dir = pos[roles["l_hip"], :2] - pos[roles["r_hip"], :2]
    if np.linalg.norm(left_dir) < 1e-9 * span:
        left_dir = pos[roles["l_ankle"], :2] - pos[roles["r_ankle"], :2]
    centre = pos[pelvis, :2]
    arms = {}
    for s in spine:
        for c in (j for j in range(n) if parents[j] == s and j not in on_spine):
            sub = [j for j in range(n) if c in _ancestors(j, parents)]
            tip = max(sub, key=lambda j: np.linalg.norm(pos[j, :2] - centre))
            reach = pos[tip, :2] - centre
            if np.linalg.norm(reach) < _ARM_REACH * span:
                continue
            key = "l" if reach @ left_dir > 0 else "r"
            if key not in arms or np.linalg.norm(reach) > arms[key][2]:
                arms[key] = (s, tip, float(np.linalg.norm(reach)))
    if len(arms) == 2:
        chest = _lca([arms["l"][0], arms["r"][0]], parents)
        for key, (_, tip, _) in arms.items():
            chain = _path(chest, tip, parents)
            bones = _long_bones(chain, pos)
            if len(bones) >= 2 and not {bones[0][0], bones[0][1], bones[1][1]} & on_spine:
                roles[f"{key}_shoulder"], roles[f"{key}_elbow"], roles[f"{key}_wrist"] = bones[0][0], bones[0][1], bones[1][1]
            else:
                # Not two long bones of a human's proportions (glTF's BrainStem: a 0.19 m upper arm,
                # a 0.41 m forearm and hand, its right forearm joint a leaf): the arm's own joints in
                # order from the first one out at the side of the torso (a clavicle starts at the
                # spine), shoulder, elbow and, where there is one, the wrist (the gait then needs no
                # more to bring a T-posed arm down).
                side = left_dir / max(float(np.linalg.norm(left_dir)), 1e-12)
                out = [j for j in chain if abs((pos[j, :2] - centre) @ side) >= _SHOULDER_OUT * span]
                out = chain[chain.index(out[0]):] if out else []
                if len(out) >= 2 and not set(out[:3]) & on_spine:
                    roles[f"{key}_shoulder"], roles[f"{key}_elbow"] = out[0], out[1]
                    if len(out) >= 3:
                        roles[f"{key}_wrist"] = out[2]
        # Names as hints where the shape is ambiguous: an arm split into more bones (rigify's
        # upper_arm and upper_arm.001) takes its named upper arm, forearm and hand when they form
        # one chain on that side of the body.
        named = recognise_roles(joints)
        for key in "lr":
            trio = [named.get(f"{key}_{j}") for j in ("shoulder", "elbow", "wrist")]
            if None in trio:
                continue
            a, b, c = trio
            chained = a in _ancestors(b, parents)[1:] and b in _ancestors(c, parents)[1:] and chest in _ancestors(a, parents)
            this_side = ((pos[c, :2] - centre) @ left_dir > 0) == (key == "l")
            if chained and this_side:
                roles[f"{key}_shoulder"], roles[f"{key}_elbow"], roles[f"{key}_wrist"] = a, b, c
        if chest != pelvis:
            roles["chest"] = chest
        upper = spine[spine.index(chest) + 1:] if chest in spine else []
    else:
        chest, upper = None, spine[len(spine) // 2:]
    if spine and spine[0] != chest and spine[0] != top:
        roles["spine"] = spine[0]
    if len(upper) >= 3:
        roles["neck"], roles["head"] = upper[0], upper[1]
    elif len(upper) == 2:
        roles["neck"], roles["head"] = upper
    elif len(upper) == 1:
        roles["head"] = upper[0]
    return roles

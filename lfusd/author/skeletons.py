"""Recognising a character's joints by name: lfusd's joint alias table.

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

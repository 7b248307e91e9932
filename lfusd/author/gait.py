"""Gait cycles (idle, walk, run) baked into UsdSkel animations, with feet planted in the world.

How a gait is made: the gait phase advances with the distance travelled (one cycle = one
stride = two steps). Each foot is in stance for the fraction ``duty`` of the cycle; during a
stance its ankle target is a fixed world point (the *plant*, on the ground under the path at
mid-stance), during swing it moves between two consecutive plants on a lifted arc. The pelvis
follows a periodic height/sway profile, lowered where needed so both legs reach their targets,
and an analytic two-bone IK turns ankle targets into hip and knee rotations. Because plants are
world points, feet do not slide however the path turns or the ground slopes.

All posing is done as world-space *deltas* from the skeleton's bind pose in the character frame
(Z up, facing +Y, metres), so any two-legged UsdSkel character can be driven the same way: its
joints' roles come from its skeleton's shape (lfusd.author.skeletons.recognise_biped), with names
(lfusd's own, Mixamo, glTF/Blender, Unreal and SMPL) as a fallback. Feet land on the back of the
heel and push off about the ball with the toes held flat (the foot measured on the mesh, see
:attr:`CharacterRig.foot`), so no sole point sinks into the ground or slides along it.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Callable

import numpy as np
from pxr import Gf, Sdf, Usd, UsdGeom, UsdSkel, Vt

from ..errors import LfusdError
from . import human as _human
from . import skeletons as _skeletons
from .vocabulary import CYCLE_FRAMES, GAIT, SPEED, STRIDE

FPS = 24.0
GAITS = ("idle", "walk", "run")
IDLE_SECONDS = 6.0  # the idle cycle: a slow weight shift, two breaths
_SPEED_LIMITS = {"walk": 2.5, "run": 9.0}


@dataclass(frozen=True)
class GaitParams:
    """One gait at one speed: stride (m per cycle, two steps), duty factor, swing lift (m)."""

    gait: str
    speed: float
    stride: float
    duty: float
    lift: float
    height: float

    @property
    def cycle_seconds(self) -> float:
        return self.stride / self.speed if self.speed > 0 else IDLE_SECONDS


def gait_params(gait: str, speed: float, height: float = 1.75) -> GaitParams:
    """Stride and timing for ``gait`` at ``speed`` m/s for a person ``height`` m tall.

    Cadence follows measured human gait: walking about 1.8 steps/s at 1.3 m/s (rising with
    speed), running about 2.8-3.5 steps/s; a taller person takes proportionally longer steps.
    """
    if gait not in GAITS:
        raise LfusdError(f"unknown gait {gait!r}; use one of {', '.join(GAITS)}")
    if gait == "idle":
        return GaitParams("idle", 0.0, 0.0, 1.0, 0.0, height)
    if not speed > 0:
        raise LfusdError(f"speed {speed:g} m/s is not positive; give a {gait} speed > 0 m/s")
    if speed > _SPEED_LIMITS[gait]:
        raise LfusdError(
            f"{gait} speed {speed:g} m/s is above {_SPEED_LIMITS[gait]:g} m/s; "
            + ("use --gait run" if gait == "walk" else "give a slower speed")
        )
    if not (np.isfinite(height) and height > 0):
        raise LfusdError(f"character height {height:g} m is not positive; give a standing character with its head above its feet")
    k = np.sqrt(1.75 / height)
    if gait == "walk":
        steps_per_s = 1.8 * (speed / 1.3) ** 0.55 * k
        duty, lift = 0.6, 0.06 * height
    else:
        steps_per_s = (2.8 + 0.08 * speed) * k
        duty, lift = 0.35, 0.11 * height
    stride = 2.0 * speed / steps_per_s
    # A stance foot travels duty * stride relative to the hips: keep it within the legs' reach.
    stride = min(stride, 0.9 * 2.0 * 0.49 * height / duty)
    return GaitParams(gait, float(speed), float(stride), duty, float(lift), height)


# ---------------------------------------------------------------------------------------------
# Rotations (column-vector convention, batched over frames)


def _rot(axis: int, angle) -> np.ndarray:
    a = np.atleast_1d(np.asarray(angle, dtype=np.float64))
    c, s = np.cos(a), np.sin(a)
    m = np.zeros((len(a), 3, 3))
    i, j = [(1, 2), (2, 0), (0, 1)][axis]
    m[:, axis, axis] = 1.0
    m[:, i, i] = c
    m[:, j, j] = c
    m[:, i, j] = -s
    m[:, j, i] = s
    return m


def rx(a):
    return _rot(0, a)


def ry(a):
    return _rot(1, a)


def rz(a):
    return _rot(2, a)


def _unit(v: np.ndarray) -> np.ndarray:
    return v / np.maximum(np.linalg.norm(v, axis=-1, keepdims=True), 1e-12)


def _frame(b: np.ndarray, f: np.ndarray) -> np.ndarray:
    """Orthonormal basis (columns) from a bone direction b and a forward hint f."""
    e1 = _unit(b)
    e2 = _unit(f - np.sum(f * e1, axis=-1, keepdims=True) * e1)
    e3 = np.cross(e1, e2)
    return np.stack([e1, e2, e3], axis=-1)


def _align(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """The smallest rotation taking unit vector a to unit vector b (3x3)."""
    a, b = _unit(np.asarray(a, float)), _unit(np.asarray(b, float))
    v, c = np.cross(a, b), float(a @ b)
    if c < -0.999999:
        axis = _unit(np.cross(a, [1.0, 0, 0]) if abs(a[0]) < 0.9 else np.cross(a, [0, 1.0, 0]))
        return 2 * np.outer(axis, axis) - np.eye(3)
    vx = np.array([[0, -v[2], v[1]], [v[2], 0, -v[0]], [-v[1], v[0], 0]])
    return np.eye(3) + vx + vx @ vx / (1 + c)


# ---------------------------------------------------------------------------------------------
# Characters


# Roles and the joint alias table live in lfusd.author.skeletons (documented in docs/CONVENTIONS.md).
ROLES, REQUIRED_ROLES, recognise_roles = _skeletons.ROLES, _skeletons.REQUIRED_ROLES, _skeletons.recognise_roles


@dataclass
class CharacterRig:
    """What the gait solver needs of a skeleton.

    ``bind`` holds the skeleton-space bind matrices (column convention); ``skel_to_char`` maps
    skeleton space to the character frame (Z up, facing +Y, metres).
    """

    joints: list[str]
    parents: np.ndarray
    bind: np.ndarray
    roles: dict[str, int]
    skel_to_char: np.ndarray = field(default_factory=lambda: np.eye(4))
    #: The foot measured on its mesh, metres in the character frame: (heel, ball, tip) offsets
    #: forward of the ankle and the ankle's height above the sole; None: estimated from the joints.
    foot_shape: tuple[float, float, float, float] | None = None

    def __post_init__(self):
        missing = [r for r in REQUIRED_ROLES if r not in self.roles]
        if missing:
            raise LfusdError(
                f"skeleton has no joints recognisable as {', '.join(missing)}; rename them to names of lfusd's "
                f"joint alias table (docs/CONVENTIONS.md, Characters), e.g. "
                + ", ".join(_skeletons.expected_names(r) for r in missing[:3])
            )
        self.char_bind = np.einsum("ij,njk->nik", self.skel_to_char, self.bind)
        scale = np.cbrt(abs(np.linalg.det(self.skel_to_char[:3, :3])))
        self.char_rot = self.char_bind[:, :3, :3] / scale  # rest orientation in the character frame
        self.rest = self.char_bind[:, :3, 3]

    def pos(self, role: str) -> np.ndarray:
        return self.rest[self.roles[role]]

    @property
    def ankle_height(self) -> float:
        """The ankles' height above the soles (the character frame's z = 0 unless measured)."""
        if self.foot_shape is not None:
            return float(self.foot_shape[3])
        return float(0.5 * (self.pos("l_ankle")[2] + self.pos("r_ankle")[2]))

    @property
    def foot(self) -> tuple[float, float, float]:
        """(heel, ball, tip): how far the sole's back, the ball (toe joint) and the toe tip lie
        forward of the ankle, metres; without a measured foot, from the toe joint (or stature)."""
        if self.foot_shape is not None:
            return tuple(float(v) for v in self.foot_shape[:3])
        if "l_toe" in self.roles:
            ball = float(abs(self.pos("l_toe")[1] - self.pos("l_ankle")[1]))
        else:
            ball = 0.1 * self.height
        return -0.3 * ball, ball, ball

    def leg_length(self, side: str) -> tuple[float, float]:
        hip, knee, ankle = (self.pos(f"{side}_{j}") for j in ("hip", "knee", "ankle"))
        return float(np.linalg.norm(knee - hip)), float(np.linalg.norm(ankle - knee))

    @property
    def height(self) -> float:
        """Approximate stature from the head (or pelvis) joint height, lfusd's proportions."""
        if "head" in self.roles:
            return float(self.pos("head")[2] / 0.895)
        return float(self.pos("pelvis")[2] / 0.555)


def human_rig(spec: _human.HumanSpec = _human.HumanSpec()) -> CharacterRig:
    """The rig of lfusd's procedural human (skeleton space is the character frame)."""
    bind, _ = _human.rest_transforms(spec)
    bind = np.array([np.array(m).T for m in bind])
    joints = _human.joint_paths()
    return CharacterRig(joints, _human.parent_indices(), bind, recognise_roles(joints), foot_shape=_human.foot_shape(spec))


def check_joint_paths(skel: UsdSkel.Skeleton) -> None:
    """Refuse joint tokens that are no valid path (UsdSkel would read them, with warnings, as a flat list)."""
    joints = [str(j) for j in skel.GetJointsAttr().Get() or []]
    bad = next((j for j in joints if not Sdf.Path.IsValidPathString(j)[0]), None)
    if bad is not None:
        raise LfusdError(
            f"skeleton {skel.GetPath()}'s joint {bad!r} is not a valid UsdSkel joint path (a prim path such as "
            "Hips/Spine; no ':' or spaces); rename its joints (e.g. mixamorig:Hips -> mixamorig_Hips)"
        )


def rig_from_skeleton(skel: UsdSkel.Skeleton, skel_to_char: np.ndarray) -> CharacterRig:
    """The rig of any UsdSkel skeleton (joints recognised by name, bind pose as rest)."""
    joints = [str(j) for j in skel.GetJointsAttr().Get() or []]
    if not joints:
        raise LfusdError(f"skeleton {skel.GetPath()} has no joints; author its joints attribute")
    bind = skel.GetBindTransformsAttr().Get()
    if not bind or len(bind) != len(joints):
        raise LfusdError(f"skeleton {skel.GetPath()} has no bindTransforms for its {len(joints)} joints; author them")
    check_joint_paths(skel)
    topo = UsdSkel.Topology(Vt.TokenArray(joints))
    ok, why = topo.Validate()
    if not ok:
        raise LfusdError(f"skeleton {skel.GetPath()} has an invalid joint hierarchy ({why}); fix its joints")
    parents = np.array(topo.GetParentIndices())
    bind = np.array([np.array(m).T for m in bind])
    if not np.all(np.isfinite(bind)):
        raise LfusdError(f"skeleton {skel.GetPath()} has non-finite bindTransforms; re-export it with a valid bind pose")
    lin = bind[:, :3, :3]
    off = np.abs(np.einsum("nji,njk->nik", lin, lin) - np.eye(3)).max(axis=(1, 2))
    if off.max() > 1e-4:
        bad = joints[int(np.argmax(off))]
        raise LfusdError(
            f"skeleton {skel.GetPath()}'s bind transform of joint {bad} scales or shears; lfusd animates rigid joints: "
            "re-export with unscaled joints (put the scale on a prim above the skeleton)"
        )
    return CharacterRig(joints, parents, bind, skeleton_roles(skel, joints, parents, bind, skel_to_char), skel_to_char)


def skeleton_roles(skel: UsdSkel.Skeleton, joints: list[str], parents: np.ndarray, bind: np.ndarray,
                   skel_to_char: np.ndarray) -> dict[str, int]:
    """Roles of a skeleton's joints: from its shape (lfusd.author.skeletons.recognise_biped, in
    the frame ``skel_to_char`` gives, whose +Z must be up), else from its joint names (the alias
    table); refuses, in one line, a skeleton that is neither."""
    pos = np.einsum("ij,njk->nik", skel_to_char, bind)[:, :3, 3]
    try:
        return _skeletons.recognise_biped(joints, parents, pos)
    except _skeletons.NotABiped as e:
        why = str(e)
    roles = recognise_roles(joints)
    if all(r in roles for r in REQUIRED_ROLES):
        return roles
    raise LfusdError(
        f"skeleton {skel.GetPath()} is not a biped lfusd can walk: {why}; give a two-legged character standing upright "
        "along its file's upAxis (docs/CONVENTIONS.md, Characters)"
    )


# ---------------------------------------------------------------------------------------------
# Motion


@dataclass
class Trajectory:
    """Where the character's root is at each frame and where the path goes.

    ``distance[f]`` is the arc length travelled at frame f; ``path_at(s)`` gives the (x, y) and
    heading (radians from +X) of the path at arc lengths ``s`` (extrapolated beyond its ends);
    ``ground(xy)`` gives the supporting surface height under points (N, 2).

    ``phase_table`` = (distances, gait phase, activity), increasing in distance from 0 to the
    path's end, describes a journey that starts and ends at rest: the phase (in cycles) reached
    at each distance, ending on a whole half-cycle, and how far the gait is developed (0 at rest,
    1 at full speed). Without it the motion is a steady, endless cycle (phase = distance / stride).
    """

    frames: np.ndarray
    distance: np.ndarray
    path_at: Callable[[np.ndarray], tuple[np.ndarray, np.ndarray]]
    ground: Callable[[np.ndarray], np.ndarray]
    phase_table: tuple[np.ndarray, np.ndarray, np.ndarray] | None = None


@dataclass
class Motion:
    """A baked motion: root (world from character frame, per frame) and joint locals (skeleton space)."""

    frames: np.ndarray
    root: np.ndarray  # (F, 4, 4) column convention
    local: np.ndarray  # (F, J, 4, 4) column convention
    ankles_world: np.ndarray  # (F, 2, 3) ankle targets, left and right
    stance: np.ndarray  # (F, 2) bool


def _smoothstep(x):
    x = np.clip(x, 0.0, 1.0)
    return x * x * (3 - 2 * x)


# Foot roll per gait: landing pitch (toe up), push-off pitch (heel up), and the cycle fractions
# over which the foot lands on its heel and rolls off its ball (measured gait: ~15 and ~30 deg).
_ROLL = {"walk": (0.25, 0.5, 0.08, 0.2), "run": (0.1, 0.5, 0.05, 0.12)}


def _roll_offset(theta: np.ndarray, pivot: np.ndarray) -> np.ndarray:
    """(forward, up) move of the ankle when the foot pitches by ``theta`` about a sole ``pivot``."""
    c, s = np.cos(theta), np.sin(theta)
    vy, vz = -pivot[0], -pivot[1]
    return np.column_stack([pivot[0] + vy * c - vz * s, pivot[1] + vy * s + vz * c])


def _pitched(offset: np.ndarray, angle: np.ndarray) -> np.ndarray:
    """(forward, up) offsets turned toe-up by ``angle`` (a foot resting on a slope)."""
    c, s = np.cos(angle), np.sin(angle)
    return np.column_stack([offset[:, 0] * c - offset[:, 1] * s, offset[:, 0] * s + offset[:, 1] * c])


def bake(rig: CharacterRig, params: GaitParams, traj: Trajectory, fps: float = FPS) -> Motion:
    """Pose ``rig`` at every frame of ``traj`` with gait ``params``.

    The steps, each a function below: the root follows the path (:func:`_root_along`); each foot
    gets a world target per frame, planted or stepping (:func:`_foot_targets`), and an orientation
    (:func:`_foot_rotations`); the upper body moves with the gait's phase (:func:`_body_motion`);
    the pelvis is lowered where a leg could not reach (:func:`_pelvis`); the joints are posed from
    the root down, the legs by two-bone IK (:func:`_pose_joints`); and the poses become the
    skeleton's joint-local matrices (:func:`_skeleton_locals`).
    """
    F = len(traj.frames)
    s = np.asarray(traj.distance, dtype=np.float64)
    moving = params.gait != "idle"
    clock = _Clock(traj.phase_table if moving else None, params.stride if moving else 1.0, moving)
    t = (traj.frames - traj.frames[0]) / fps
    phi = clock.phase_at(s) if moving else np.zeros(F)
    act = clock.act_of(s)  # scales the upper body's motion and the foot roll with the gait's development

    xy, heading = traj.path_at(s)
    root = _root_along(xy, heading, traj.ground(xy))
    sole = _Sole.of(rig, params.gait)
    targets, foot_yaw, pitch, stance = _foot_targets(rig, params, traj, clock, sole, phi, act, xy, heading)

    # --- Everything below is in the character frame (root^-1 * world).
    inv_rot = np.transpose(root[:, :3, :3], (0, 2, 1))
    tgt_c = np.einsum("fij,fkj->fki", inv_rot, targets - root[:, None, :3, 3])
    foot_rot, toe_rot = _foot_rotations(traj, sole, targets, foot_yaw, pitch, heading)
    body = _body_motion(params, rig.height, phi, act, t, F)
    d_pelvis = rz(body.pel_yaw) @ ry(body.pel_roll)
    pel = _pelvis(rig, body, d_pelvis, tgt_c, act, moving, F)
    upper = _upper_body(rig, body, d_pelvis, F)
    D, P = _pose_joints(rig, pel, upper, d_pelvis, tgt_c, foot_rot, toe_rot, F)
    return Motion(np.asarray(traj.frames), root, _skeleton_locals(rig, D, P), targets, stance)


@dataclass(frozen=True)
class _Clock:
    """The gait's phase (in cycles) against the distance travelled, and its development
    (activity: 0 at rest, 1 at full speed), from a journey's ``table`` (Trajectory.phase_table)
    or, without one, a steady cycle of one ``stride`` per cycle."""

    table: tuple[np.ndarray, np.ndarray, np.ndarray] | None
    stride: float
    moving: bool

    def phase_at(self, dist):
        return np.interp(dist, self.table[0], self.table[1]) if self.table is not None else np.asarray(dist) / self.stride

    def dist_at(self, phase):
        # With a journey, distances clamp to the path: before and after it the person stands.
        return np.interp(phase, self.table[1], self.table[0]) if self.table is not None else np.asarray(phase) * self.stride

    def act_of(self, dist):
        if self.table is None:
            return np.full(np.shape(dist), 1.0 if self.moving else 0.0)
        return np.interp(dist, self.table[0], self.table[2])


def _root_along(xy: np.ndarray, heading: np.ndarray, root_z: np.ndarray) -> np.ndarray:
    """(F, 4, 4) root matrices: on the path at the ground's height, the character (facing +Y) facing along it."""
    yaw = heading - np.pi / 2  # the character faces +Y
    root = np.tile(np.eye(4), (len(xy), 1, 1))
    root[:, :3, :3] = rz(yaw)
    root[:, :2, 3] = xy
    root[:, 2, 3] = root_z
    return root


@dataclass(frozen=True)
class _Sole:
    """The foot against the ground: the ankle's height above the sole, (heel, ball, tip) forward
    of the ankle, the pivots in the foot's (forward, up) plane relative to the ankle about which it
    lands (the back of its heel) and pushes off (its ball; its tip without toe joints), and the
    gait's foot roll (:data:`_ROLL`)."""

    ankle_h: float
    heel_fwd: float
    ball_fwd: float
    tip_fwd: float
    heel_pt: np.ndarray
    ball_pt: np.ndarray
    has_toes: bool
    roll: tuple[float, float, float, float]

    @classmethod
    def of(cls, rig: CharacterRig, gait: str) -> "_Sole":
        ankle_h = rig.ankle_height
        heel_fwd, ball_fwd, tip_fwd = rig.foot
        has_toes = "l_toe" in rig.roles and "r_toe" in rig.roles
        heel_pt = np.array([heel_fwd, -ankle_h])
        ball_pt = np.array([tip_fwd, -ankle_h])
        if has_toes:
            # Halfway between the sole and the toe joint: turning the foot about the sole would slide
            # the toes (held flat, they turn about their joint), about the joint the sole under it.
            joint = float(rig.pos("l_toe")[2] - rig.pos("l_ankle")[2])
            ball_pt = np.array([ball_fwd, 0.5 * (joint - ankle_h)])
        return cls(ankle_h, heel_fwd, ball_fwd, tip_fwd, heel_pt, ball_pt, has_toes, _ROLL.get(gait, (0.0, 0.0, 0.1, 0.1)))


def _foot_targets(rig: CharacterRig, params: GaitParams, traj: Trajectory, clock: _Clock, sole: _Sole,
                  phi: np.ndarray, act: np.ndarray, xy: np.ndarray, heading: np.ndarray):
    """Per frame and side (left, right): the ankle's world target, the foot's yaw and pitch, and
    whether it is in stance. Standing, both feet stay beside the root; moving, each plants at
    mid-stance under the path (:func:`_stepping_foot`), the right half a cycle after the left."""
    F = len(phi)
    half_width = 0.5 * abs(rig.pos("l_ankle")[0] - rig.pos("r_ankle")[0])
    targets = np.zeros((F, 2, 3))
    foot_yaw = np.zeros((F, 2))
    pitch = np.zeros((F, 2))
    stance = np.zeros((F, 2), bool)
    for k, (side, offset) in enumerate((("l", 0.0), ("r", 0.5))):
        lateral = -half_width if side == "l" else half_width
        if params.gait == "idle":
            fxy, _ = _beside(xy, heading, lateral)
            targets[:, k, :2] = fxy
            targets[:, k, 2] = traj.ground(fxy) + sole.ankle_h
            foot_yaw[:, k] = heading
            stance[:, k] = True
            continue
        targets[:, k], foot_yaw[:, k], pitch[:, k], stance[:, k] = _stepping_foot(params, traj, clock, sole, phi, act, offset, lateral)
    return targets, foot_yaw, pitch, stance


def _beside(pxy: np.ndarray, ph: np.ndarray, lateral: float) -> tuple[np.ndarray, np.ndarray]:
    """Points ``lateral`` metres to the right of path points ``pxy`` with headings ``ph``, and the headings."""
    c, sn = np.cos(ph - np.pi / 2), np.sin(ph - np.pi / 2)
    return pxy + np.stack([lateral * c, lateral * sn], axis=1), ph


def _duty(cycle, beta: float, offset: float, table, phi_end: float):
    """The stance fraction of each ``cycle``: a run's first and last stances are long (walk-like),
    so the person stands with both feet down before setting off and after stopping at a half-cycle."""
    if table is None or beta >= 0.55:
        return np.full(np.shape(cycle), beta)
    ends = (cycle + offset <= 0) | (cycle + offset > phi_end - 0.6 - 1e-9)
    return np.where(ends, 0.6, beta)


def _ground_pitch(traj: Trajectory, sole: _Sole, sm: np.ndarray, lateral: float) -> np.ndarray:
    """The ground's pitch along the foot (heel to ball) planted at arc lengths ``sm``; a step edge
    (steeper than 20 degrees) leaves the foot level."""
    fxy, ph = _beside(*traj.path_at(sm), lateral)
    fwd = np.column_stack([np.cos(ph), np.sin(ph)])
    zb, zh = traj.ground(fxy + fwd * sole.ball_pt[0]), traj.ground(fxy + fwd * sole.heel_pt[0])
    a = np.arctan2(zb - zh, sole.ball_pt[0] - sole.heel_pt[0])
    return np.where(np.abs(a) < np.radians(20), a, 0.0)


def _stepping_foot(params: GaitParams, traj: Trajectory, clock: _Clock, sole: _Sole, phi: np.ndarray, act: np.ndarray,
                   offset: float, lateral: float):
    """One foot of a moving gait, its cycle ``offset`` after the left: (target, yaw, pitch, stance)
    per frame. In stance the foot stays on its plant n (rolling heel to toe about fixed pivots); in
    swing it moves along the path from plant n to plant n+1 on a lifted arc."""
    S, beta = clock.stride, params.duty
    th0, th1, r1, r2 = sole.roll
    n = np.floor(phi - offset)
    local = phi - offset - n
    phi_end = clock.table[1][-1] if clock.table is not None else np.inf

    def plant_s(cycle):
        return clock.dist_at(cycle + offset + _duty(cycle, beta, offset, clock.table, phi_end) / 2)  # where mid-stance is reached

    def plant(sm):
        fxy, ph = _beside(*traj.path_at(sm), lateral)
        return np.column_stack([fxy, traj.ground(fxy) + sole.ankle_h]), ph

    s0, s1 = plant_s(n), plant_s(n + 1)
    p0, h0 = plant(s0)
    p1, h1 = plant(s1)
    g0, g1 = _ground_pitch(traj, sole, s0, lateral), _ground_pitch(traj, sole, s1, lateral)
    h1 = h0 + (h1 - h0 + np.pi) % (2 * np.pi) - np.pi
    b0 = _duty(n, beta, offset, clock.table, phi_end)
    in_stance = local < b0
    u = np.clip((local - b0) / (1 - b0), 0.0, 1.0)
    w = 0.5 - 0.5 * np.cos(np.pi * u)
    # Swing along the path (not the chord between plants), so feet do not cross on turns.
    sxy, _ = _beside(*traj.path_at(s0 + (s1 - s0) * w), lateral)
    swing = np.column_stack([sxy, p0[:, 2] + (p1[:, 2] - p0[:, 2]) * w])
    # Short steps (setting off, stopping) lift the foot less.
    lift = params.lift * np.clip(np.abs(s1 - s0) / (S * max(beta, 0.5)), 0.25, 1.0)
    swing[:, 2] += lift * np.sin(np.pi * u)
    # Heel-to-toe roll: the foot lands toe-up pivoting on the heel and leaves heel-up pivoting
    # on the ball; the pivot stays put, so the contact does not slide while the ankle moves.
    leave0, land1 = clock.act_of(clock.dist_at(n + offset + b0)), clock.act_of(clock.dist_at(n + 1 + offset))
    # Landing rolls as much as the gait was developed when the foot landed; pushing off
    # follows the momentary activity (none while standing still), which is leave0 at toe-off,
    # so stance and swing join up at both ends.
    land0 = clock.act_of(clock.dist_at(n + offset))
    th_in = th0 * land0 * (1 - _smoothstep(local / r1))
    th_out = -th1 * act * _smoothstep((local - (b0 - r2)) / r2)
    st_off = _pitched(np.where((local < r1)[:, None], _roll_offset(th_in, sole.heel_pt), _roll_offset(th_out, sole.ball_pt)), g0)
    st_pitch = g0 + np.where(local < r1, th_in, th_out)
    off_out = _pitched(_roll_offset(-th1 * leave0, sole.ball_pt), g0)  # at toe-off of plant n
    off_in = _pitched(_roll_offset(th0 * land1, sole.heel_pt), g1)  # landing on plant n+1
    sw_off = off_out + (off_in - off_out) * w[:, None]
    sw_pitch = (g0 - th1 * leave0) * (1 - w) + (g1 + th0 * land1) * w
    off = np.where(in_stance[:, None], st_off, sw_off)
    yaw_k = np.where(in_stance, h0, h0 + (h1 - h0) * w)
    fwd = np.column_stack([np.cos(yaw_k), np.sin(yaw_k)])
    target = np.where(in_stance[:, None], p0, swing)
    target[:, :2] += fwd * off[:, :1]
    target[:, 2] += off[:, 1]
    return target, yaw_k, np.where(in_stance, st_pitch, sw_pitch), in_stance


def _foot_rotations(traj: Trajectory, sole: _Sole, targets: np.ndarray, foot_yaw: np.ndarray, pitch: np.ndarray,
                    heading: np.ndarray) -> tuple[list[np.ndarray], list[np.ndarray]]:
    """Per side, the foot's and the toes' rotations in the character frame. Toes bend at the ball:
    they never point down into the ground's slope, so they stay flat on the ground while the heel
    rises and lift with the ball when the foot leaves it."""
    foot_rot = [rz(foot_yaw[:, k] - heading) @ rx(pitch[:, k]) for k in range(2)]
    toe_rot = foot_rot
    toe_len = sole.tip_fwd - sole.ball_fwd
    if sole.has_toes and toe_len > 1e-3:
        toe_rot = []
        for k in range(2):
            fwd = np.column_stack([np.cos(foot_yaw[:, k]), np.sin(foot_yaw[:, k])])
            ball_xy = targets[:, k, :2] + fwd * (np.cos(pitch[:, k]) * sole.ball_pt[0] - np.sin(pitch[:, k]) * sole.ball_pt[1])[:, None]
            slope_t = np.arctan2(traj.ground(ball_xy + fwd * toe_len) - traj.ground(ball_xy), toe_len)
            slope_t = np.where(np.abs(slope_t) < np.radians(20), slope_t, 0.0)
            toe_rot.append(rz(foot_yaw[:, k] - heading) @ rx(np.maximum(pitch[:, k], slope_t)))
    return foot_rot, toe_rot


@dataclass(frozen=True)
class _Body:
    """The upper body's motion per frame: pelvis height (bob), sideways sway, yaw and roll, the
    arms' swing, the torso's lean and the elbows' bend."""

    bob: np.ndarray
    pel_x: np.ndarray
    pel_yaw: np.ndarray
    pel_roll: np.ndarray
    arm: np.ndarray
    lean: np.ndarray
    elbow: np.ndarray


def _body_motion(params: GaitParams, H: float, phi: np.ndarray, act: np.ndarray, t: np.ndarray, F: int) -> _Body:
    """Walk and run: periodic in the gait phase ``phi``, scaled by the activity; idle: breathing
    and a slow weight shift over time ``t``. ``H``: the character's stature."""
    moving = params.gait != "idle"
    beta = params.duty
    two_pi_phi = 2 * np.pi * phi
    mid = 2 * np.pi * (phi - beta / 2)  # 0 at left mid-stance
    if params.gait == "walk":
        bob = 0.012 * H * np.cos(2 * mid)  # highest at mid-stance (vaulting over the stance leg)
        sway, yaw_amp, roll_amp, lean, arm_amp, elbow = 0.012 * H, 0.09, 0.05, 0.04, 0.35, 0.25
    elif params.gait == "run":
        bob = -0.02 * H * np.cos(2 * mid)  # lowest at mid-stance, highest in flight
        sway, yaw_amp, roll_amp, lean, arm_amp, elbow = 0.006 * H, 0.12, 0.04, 0.15, 0.45, 1.3
    else:  # idle: breathing and a slow weight shift
        bob = 0.003 * H * np.sin(2 * np.pi * t / (IDLE_SECONDS / 2))
        sway, yaw_amp, roll_amp, lean, arm_amp, elbow = 0.0, 0.0, 0.0, 0.0, 0.0, 0.15
    if moving:
        pel_x = -sway * np.cos(mid) * act
        pel_yaw = -yaw_amp * np.cos(two_pi_phi) * act
        pel_roll = roll_amp * np.cos(mid) * act
        arm = -arm_amp * np.cos(two_pi_phi) * act  # left arm swings against the left leg
        lean_a = lean * act
        bob = bob * act
        elbow_a = 0.15 + (elbow - 0.15) * act
    else:
        pel_x = 0.01 * H * np.sin(2 * np.pi * t / IDLE_SECONDS)
        pel_yaw = 0.02 * np.sin(2 * np.pi * t / IDLE_SECONDS)
        pel_roll = -0.02 * np.sin(2 * np.pi * t / IDLE_SECONDS)
        arm = 0.03 * np.sin(2 * np.pi * t / (IDLE_SECONDS / 2))
        lean_a = np.zeros(F)
        elbow_a = np.full(F, elbow)
    return _Body(bob, pel_x, pel_yaw, pel_roll, arm, lean_a, elbow_a)


def _pelvis(rig: CharacterRig, body: _Body, d_pelvis: np.ndarray, tgt_c: np.ndarray, act: np.ndarray, moving: bool,
            F: int) -> np.ndarray:
    """The pelvis position per frame (character frame): its rest position moved by the body's
    sway and bob, lowered a little with the gait, and further where a leg could not otherwise
    reach its ankle target ``tgt_c``."""
    H = rig.height
    pelvis_rest = rig.pos("pelvis")
    pel = np.tile(pelvis_rest, (F, 1))
    pel[:, 0] += body.pel_x
    pel[:, 2] += body.bob - (0.01 * H if moving else 0.005 * H) * np.maximum(act, 0.0 if moving else 1.0)
    for k, side in enumerate("lr"):
        l1, l2 = rig.leg_length(side)
        reach = 0.995 * (l1 + l2)
        hip_off = np.einsum("fij,j->fi", d_pelvis, rig.pos(f"{side}_hip") - pelvis_rest)
        dxy = np.linalg.norm(pel[:, :2] + hip_off[:, :2] - tgt_c[:, k, :2], axis=1)
        zmax = tgt_c[:, k, 2] - hip_off[:, 2] + np.sqrt(np.maximum(reach**2 - dxy**2, 0.0))
        pel[:, 2] = np.minimum(pel[:, 2], zmax)
    return pel


def _upper_body(rig: CharacterRig, body: _Body, d_pelvis: np.ndarray, F: int) -> dict[str, np.ndarray]:
    """Role -> (F, 3, 3) rotation in the character frame of the pelvis, spine, chest, neck, head
    and arms. Arms hang in lfusd's A-pose direction whatever the character's rest pose (e.g. a T-pose)."""
    R = rig.roles
    upper = {
        "pelvis": d_pelvis,
        "spine": rz(-0.3 * body.pel_yaw) @ rx(-0.5 * body.lean),
        "chest": rz(0.6 * body.pel_yaw) @ rx(-body.lean),
        "neck": rx(-0.5 * body.lean),
        "head": np.tile(np.eye(3), (F, 1, 1)),
    }
    for side, sgn in (("l", 1.0), ("r", -1.0)):
        hang = np.array([(-1 if side == "l" else 1) * np.sin(np.radians(_human.ARM_OUT_DEG)), 0.0, -np.cos(np.radians(_human.ARM_OUT_DEG))])
        segs = [(f"{side}_shoulder", f"{side}_elbow"), (f"{side}_elbow", f"{side}_wrist")]
        swing = sgn * body.arm
        for j, (a, b) in enumerate(segs):
            if a not in R or b not in R:
                continue
            align = _align(rig.pos(b) - rig.pos(a), hang)
            bend = rx(swing) if j == 0 else rx(swing + body.elbow)
            upper[a] = upper["chest"] @ bend @ align
        if f"{side}_wrist" in R and f"{side}_elbow" in upper:
            upper[f"{side}_wrist"] = upper[f"{side}_elbow"]
    return upper


def _leg_ik(rig: CharacterRig, side: str, hip_joint: int, hip: np.ndarray, target: np.ndarray, d_pelvis: np.ndarray,
            foot_rot: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Analytic two-bone IK: the hip's and the knee's rotations (character frame) that put the
    ankle at ``target`` (clamped to the leg's reach), the knee bending forward (the pelvis's and
    the foot's forward direction)."""
    R = rig.roles
    j = hip_joint
    ki, ai = R[f"{side}_knee"], R[f"{side}_ankle"]
    l1, l2 = rig.leg_length(side)
    to = target - hip
    d = np.clip(np.linalg.norm(to, axis=1), abs(l1 - l2) + 1e-6, (l1 + l2) * (1 - 1e-9))
    u = _unit(to)
    fwd = _unit(np.einsum("fij,j->fi", d_pelvis, [0, 1.0, 0]) + foot_rot[:, :, 1])
    wv = _unit(fwd - np.sum(fwd * u, axis=1, keepdims=True) * u)
    cos_a = np.clip((l1**2 + d**2 - l2**2) / (2 * l1 * d), -1, 1)
    knee = hip + l1 * (cos_a[:, None] * u + np.sqrt(1 - cos_a**2)[:, None] * wv)
    ankle = hip + u * d[:, None]
    rest_f = np.array([0, 1.0, 0])
    r_thigh = _frame(rig.rest[ki] - rig.rest[j], rest_f)
    r_shin = _frame(rig.rest[ai] - rig.rest[ki], rest_f)
    return _frame(knee - hip, fwd) @ r_thigh.T, _frame(ankle - knee, fwd) @ r_shin.T


def _pose_joints(rig: CharacterRig, pel: np.ndarray, upper: dict[str, np.ndarray], d_pelvis: np.ndarray, tgt_c: np.ndarray,
                 foot_rot: list[np.ndarray], toe_rot: list[np.ndarray], F: int) -> tuple[np.ndarray, np.ndarray]:
    """Every joint's rotation D (F, J, 3, 3) and position P (F, J, 3) in the character frame, from
    the root down: a joint follows its parent rigidly unless its role is posed (the pelvis's
    position, the ``upper`` body's rotations, the legs by :func:`_leg_ik`, the feet and toes)."""
    D = np.tile(np.eye(3), (F, len(rig.joints), 1, 1))
    P = np.zeros((F, len(rig.joints), 3))
    R = rig.roles
    upper = dict(upper)  # the legs add their knee, ankle and toe rotations as they are solved
    for j in range(len(rig.joints)):
        p = rig.parents[j]
        if p < 0:
            P[:, j] = rig.rest[j]
        else:
            P[:, j] = P[:, p] + np.einsum("fij,j->fi", D[:, p], rig.rest[j] - rig.rest[p])
            D[:, j] = D[:, p]
        role = next((r for r, i in R.items() if i == j), None)
        if role == "pelvis":
            P[:, j] = pel
        if role in upper:
            D[:, j] = upper[role]
        elif role and role[2:] == "hip":
            k = 0 if role[0] == "l" else 1
            side = role[0]
            D[:, j], upper[f"{side}_knee"] = _leg_ik(rig, side, j, P[:, j], tgt_c[:, k], d_pelvis, foot_rot[k])
            upper[f"{side}_ankle"] = foot_rot[k]
            if f"{side}_toe" in R:
                upper[f"{side}_toe"] = toe_rot[k]
    return D, P


def _skeleton_locals(rig: CharacterRig, D: np.ndarray, P: np.ndarray) -> np.ndarray:
    """Joint-local matrices (F, J, 4, 4) in skeleton space: G_j = C^-1 M_j C B_j, with M_j the
    rigid motion of joint j (D, P against the rest pose), each then relative to its parent's G."""
    F = len(D)
    C = rig.skel_to_char
    Ci = np.linalg.inv(C)
    M = np.tile(np.eye(4), (F, len(rig.joints), 1, 1))
    M[..., :3, :3] = D
    M[..., :3, 3] = P - np.einsum("fjik,jk->fji", D, rig.rest)
    G = np.einsum("ab,fjbc,cd,jde->fjae", Ci, M, C, rig.bind)
    L = G.copy()
    for j in range(len(rig.joints)):
        if rig.parents[j] >= 0:
            L[:, j] = np.linalg.inv(G[:, rig.parents[j]]) @ G[:, j]
    return L


# ---------------------------------------------------------------------------------------------
# Writing


def write_motion(stage: Usd.Stage, skel_path: Sdf.Path | str, rig: CharacterRig, motion: Motion,
                 root_prim: Usd.Prim, extra_ops: np.ndarray | None = None,
                 stage_ops: np.ndarray | None = None) -> UsdSkel.Animation:
    """Author ``motion``: a UsdSkel Animation bound to the skeleton, and the root's time samples.

    Joint translations and rotations are sampled every frame (scales are constant 1); the root
    prim gets ``xformOp:translate`` and ``xformOp:rotateZ`` samples (world from character frame)
    followed, for user characters, by a constant ``xformOp:transform`` (``extra_ops``: character
    frame from the prim's own space: units, up axis, facing), all preceded, on stages that are
    not Z-up metres (or whose parent prims are transformed), by a constant
    ``xformOp:transform:stage`` (``stage_ops``: the parent's space from lfusd's world).
    """
    skel_path = Sdf.Path(str(skel_path))
    anim = UsdSkel.Animation.Define(stage, skel_path.AppendChild(_human.ANIMATION_NAME))
    anim.CreateJointsAttr(Vt.TokenArray(rig.joints))
    UsdSkel.BindingAPI.Apply(stage.GetPrimAtPath(skel_path)).CreateAnimationSourceRel().SetTargets([anim.GetPath()])
    t_attr, r_attr = anim.CreateTranslationsAttr(), anim.CreateRotationsAttr()
    for f, local in zip(motion.frames, motion.local):
        mats = Vt.Matrix4dArray([Gf.Matrix4d(*m.T.ravel().tolist()) for m in local])
        translations, rotations, scales = UsdSkel.DecomposeTransforms(mats)
        t_attr.Set(translations, Usd.TimeCode(float(f)))
        r_attr.Set(rotations, Usd.TimeCode(float(f)))
    anim.CreateScalesAttr().Set(Vt.Vec3hArray([Gf.Vec3h(1, 1, 1)] * len(rig.joints)))
    xf = UsdGeom.Xformable(root_prim)
    xf.ClearXformOpOrder()
    if stage_ops is not None and not np.allclose(stage_ops, np.eye(4), rtol=0, atol=1e-12):
        xf.AddTransformOp(opSuffix="stage").Set(Gf.Matrix4d(*np.asarray(stage_ops).T.ravel().tolist()))
    move, turn = xf.AddTranslateOp(), xf.AddRotateZOp()
    # Unwrapped, so that samples never jump by 360 degrees (sub-frame interpolation stays a turn).
    yaw = np.degrees(np.unwrap(np.arctan2(motion.root[:, 1, 0], motion.root[:, 0, 0])))
    for f, m, a in zip(motion.frames, motion.root, yaw):
        move.Set(Gf.Vec3d(*m[:3, 3].tolist()), Usd.TimeCode(float(f)))
        turn.Set(float(a), Usd.TimeCode(float(f)))
    if extra_ops is not None and not np.allclose(extra_ops, np.eye(4)):
        xf.AddTransformOp().Set(Gf.Matrix4d(*np.asarray(extra_ops).T.ravel().tolist()))
    return anim


def straight_trajectory(frames: np.ndarray, speed: float, fps: float = FPS) -> Trajectory:
    """Walking along +Y from the origin on flat ground z = 0."""
    dist = speed * (np.asarray(frames, float) - frames[0]) / fps

    def path_at(s):
        s = np.atleast_1d(np.asarray(s, float))
        return np.column_stack([np.zeros_like(s), s]), np.full(len(s), np.pi / 2)

    return Trajectory(np.asarray(frames), dist, path_at, lambda xy: np.zeros(len(xy)))


def journey(gait: str, speed: float, length: float, height: float, frames: np.ndarray, start: float,
            fps: float = FPS, accel_seconds: float | None = None):
    """(distance per frame, phase table, peak speed) for a trip of ``length`` metres from rest to rest.

    Speed rises linearly from 0 to ``speed`` over ``accel_seconds`` (default 0.6 s walking, 1.2 s
    running) after ``start``, and falls to 0 at the path's end (a shorter peak on a short path);
    strides follow the momentary speed (lfusd.author.gait.gait_params), and the stride scale is adjusted
    by at most half a step so the trip ends on a half-cycle, with both feet down.
    """
    ta = accel_seconds if accel_seconds is not None else (0.6 if gait == "walk" else 1.2)
    a = speed / ta
    peak = speed if length >= speed * ta else float(np.sqrt(length * a))
    t_acc = peak / a
    cruise = (length - peak * t_acc) / peak
    total = 2 * t_acc + cruise

    def dist(t):
        t = np.clip(t, 0.0, total)
        up = 0.5 * a * np.minimum(t, t_acc) ** 2
        mid = peak * np.clip(t - t_acc, 0.0, cruise)
        td = np.clip(t - t_acc - cruise, 0.0, t_acc)
        down = peak * td - 0.5 * a * td**2
        return up + mid + down

    d = dist((np.asarray(frames, float) - start) / fps)
    grid = np.linspace(0.0, length, max(200, int(length / 0.01)))
    v = np.minimum(peak, np.sqrt(2 * a * np.minimum(grid, length - grid)))
    vmin = 0.15 * speed  # the first and last steps are short, not infinitely so
    vs = np.linspace(vmin, speed, 32)
    stride = np.interp(np.maximum(v, vmin), vs, [gait_params(gait, float(x), height).stride for x in vs])
    rate = 1.0 / stride
    phase = np.concatenate([[0.0], np.cumsum(0.5 * (rate[1:] + rate[:-1]) * np.diff(grid))])
    half_cycles = max(1, int(round(2 * phase[-1])))
    phase *= half_cycles / (2 * phase[-1])
    return d, (grid, phase, v / speed), peak


def cycle_frames(params: GaitParams, fps: float = FPS) -> int:
    """Frames in one gait cycle, rounded to a whole number so the clip loops sample-exactly."""
    return max(8, int(round(params.cycle_seconds * fps)))


def write_cycle(path, gait: str, speed: float = 1.3, spec: _human.HumanSpec = _human.HumanSpec()) -> Usd.Stage:
    """Write a looping clip of ``gait`` (frames 1..N+1, pose N+1 = pose 1) with the procedural human.

    The root moves along +Y at ``speed``; the Animation prim alone is an in-place cycle.
    """
    from .stage import new_stage

    params = gait_params(gait, speed, spec.height)
    n = cycle_frames(params)
    if gait != "idle":
        # Adjust the stride so one cycle is exactly n frames at this speed.
        params = GaitParams(gait, speed, speed * n / FPS, params.duty, params.lift, spec.height)
    frames = np.arange(1, n + 2)
    stage = new_stage(path, 1, n + 1)
    root = _human.define_human(stage, "/World/Person", spec)
    rig = human_rig(spec)
    motion = bake(rig, params, straight_trajectory(frames, params.speed))
    write_motion(stage, root.GetPath().AppendChild(_human.SKELETON_NAME), rig, motion, root.GetPrim())
    stage.GetRootLayer().customLayerData = {
        GAIT: gait, SPEED: float(params.speed), CYCLE_FRAMES: n, STRIDE: float(params.stride),
    }
    return stage


CYCLE_FILES = {"idle": ("human_idle.usda", 0.0), "walk": ("human_walk.usda", 1.3), "run": ("human_run.usda", 3.5)}


def write_cycle_library(folder, spec: _human.HumanSpec = _human.HumanSpec()) -> list[str]:
    """Write the looping idle/walk/run clips of the procedural human into ``folder``."""
    from pathlib import Path

    out = []
    Path(folder).mkdir(parents=True, exist_ok=True)
    for gait, (name, speed) in CYCLE_FILES.items():
        path = str(Path(folder) / name)
        stage = write_cycle(path, gait, speed, spec)
        stage.GetRootLayer().Save()
        out.append(path)
    return out

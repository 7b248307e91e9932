"""Rigid movers: boats drifting and bobbing on water, cars driving with turning wheels, doors
swinging and objects sliding, as time-sampled transforms that satisfy the rulebook.

Every motion is an analytic pose per frame (:class:`RigidMotion`: a translation and USD
``rotateXYZ`` angles), authored on the mover's prim as one ``xformOp:translate`` and one
``xformOp:rotateXYZ`` (double precision, one sample per frame, or a single default value where
the component never changes), so ``motion.matrices()`` is exactly what pxr composes.

- Boats (:func:`drift_boat`) keep a point on their waterline on the water surface while it heaves
  (``bob``), and roll and pitch about that point; the range of depths of the hull's bottom is
  known in closed form (:func:`draft_band`) and authored as the boat's ``draft`` constraint, so
  ``lfusd check`` holds the boat to it at every frame.
- Cars (:func:`drive_car`) move along their heading at constant speed; child prims named
  ``wheel*`` with an ``lfusd:wheelRadius`` attribute turn about their local Y axis so they roll
  without slipping (angle = distance / radius).
- Doors (:func:`swing`) turn about their local Z axis (their origin is the hinge) and objects
  (:func:`slide`) translate over their support, both with C2-smooth easing (smootherstep), so
  velocity and acceleration are continuous and zero at the ends of each movement.

Parameters that vary between movers (wave periods, phases, amplitudes) come from
:func:`wave_params` with a seeded ``numpy.random.Generator``: the same seed gives the same motion.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from pxr import Gf, Sdf, Usd, UsdGeom

from ..errors import LfusdError
from .stage import frame_range
from .vocabulary import WHEEL_RADIUS, constraint_attr


@dataclass
class RigidMotion:
    """Poses of one prim relative to its parent: ``translate`` (N, 3) and ``rotate`` (N, 3), the
    USD ``rotateXYZ`` angles in degrees (rotation about X first, then Y, then Z) at ``frames``."""

    frames: np.ndarray
    translate: np.ndarray
    rotate: np.ndarray

    def rotations(self) -> np.ndarray:
        """(N, 3, 3) column-vector rotation matrices Rz @ Ry @ Rx."""
        return rot_xyz(self.rotate)

    def matrices(self) -> np.ndarray:
        """(N, 4, 4) column-vector local-to-parent matrices T @ Rz @ Ry @ Rx."""
        m = np.zeros((len(self.frames), 4, 4))
        m[:, :3, :3] = self.rotations()
        m[:, :3, 3] = self.translate
        m[:, 3, 3] = 1.0
        return m

    def apply(self, points: np.ndarray) -> np.ndarray:
        """(N, P, 3): local ``points`` (P, 3) placed at every frame."""
        return np.einsum("nij,pj->npi", self.rotations(), np.asarray(points, float)) + self.translate[:, None]


def rot_xyz(deg) -> np.ndarray:
    """Rotation matrices of USD rotateXYZ angles (degrees, (..., 3)): Rz(z) @ Ry(y) @ Rx(x)."""
    a = np.radians(np.asarray(deg, float))
    cx, cy, cz = np.cos(a[..., 0]), np.cos(a[..., 1]), np.cos(a[..., 2])
    sx, sy, sz = np.sin(a[..., 0]), np.sin(a[..., 1]), np.sin(a[..., 2])
    r = np.empty(a.shape[:-1] + (3, 3))
    r[..., 0, 0], r[..., 0, 1], r[..., 0, 2] = cz * cy, cz * sy * sx - sz * cx, cz * sy * cx + sz * sx
    r[..., 1, 0], r[..., 1, 1], r[..., 1, 2] = sz * cy, sz * sy * sx + cz * cx, sz * sy * cx - cz * sx
    r[..., 2, 0], r[..., 2, 1], r[..., 2, 2] = -sy, cy * sx, cy * cx
    return r


def smootherstep(x) -> np.ndarray:
    """0 before 0, 1 after 1, 6x^5 - 15x^4 + 10x^3 between: zero velocity and acceleration at both ends."""
    x = np.clip(np.asarray(x, float), 0.0, 1.0)
    return x**3 * (x * (6 * x - 15) + 10)


# -- authoring -----------------------------------------------------------------------------------
def _set(op: UsdGeom.XformOp, frames: np.ndarray, values: np.ndarray) -> None:
    if np.all(values == values[0]):  # constant: one default value keeps files small
        op.Set(Gf.Vec3d(*values[0].tolist()))
        return
    for f, v in zip(frames.tolist(), values.tolist()):
        op.Set(Gf.Vec3d(*v), Usd.TimeCode(f))


def author(prim: Usd.Prim, motion: RigidMotion) -> None:
    """Replace ``prim``'s transform with ``motion`` (translate, then rotateXYZ; double precision)."""
    xf = UsdGeom.Xformable(prim)
    if not xf:
        raise LfusdError(f"prim {prim.GetPath()} is not transformable (no Xformable schema); move an Xform or a mesh")
    for name in prim.GetPropertyNames():
        if name.startswith("xformOp:"):
            prim.RemoveProperty(name)
    xf.ClearXformOpOrder()
    _set(xf.AddTranslateOp(UsdGeom.XformOp.PrecisionDouble), motion.frames, np.asarray(motion.translate, float))
    _set(xf.AddRotateXYZOp(UsdGeom.XformOp.PrecisionDouble), motion.frames, np.asarray(motion.rotate, float))


def start_pose(prim: Usd.Prim) -> tuple[np.ndarray, float]:
    """(translation, yaw degrees) of a prim placed by a translate and an optional rotateZ op
    (as lfusd.author.scenes authors objects), read at the default time."""
    xf = UsdGeom.Xformable(prim)
    m = np.array(xf.GetLocalTransformation(Usd.TimeCode.Default()), float).T  # column-vector
    r = m[:3, :3]
    if not np.allclose(r[2], [0, 0, 1], atol=1e-9) or not np.allclose(r[:, 2], [0, 0, 1], atol=1e-9):
        raise LfusdError(f"prim {prim.GetPath()} is tilted; movers start from an upright pose (translate and rotateZ only)")
    return m[:3, 3].copy(), float(np.degrees(np.arctan2(r[1, 0], r[0, 0])))


def _frames(stage: Usd.Stage) -> tuple[np.ndarray, float]:
    first, last = frame_range(stage)
    return np.arange(first, last + 1), float(stage.GetTimeCodesPerSecond() or 24.0)


def _local_points(prim: Usd.Prim) -> np.ndarray:
    """Points of every mesh under ``prim`` in ``prim``'s own frame (at the default time)."""
    cache = UsdGeom.XformCache(Usd.TimeCode.Default())
    out = []
    for d in Usd.PrimRange(prim):
        if d.IsA(UsdGeom.Mesh):
            m, _ = cache.ComputeRelativeTransform(d, prim)
            m = np.array(m, float)
            p = np.array(UsdGeom.Mesh(d).GetPointsAttr().Get(Usd.TimeCode.Default()), float)
            out.append(p @ m[:3, :3] + m[3, :3])
    if not out:
        raise LfusdError(f"prim {prim.GetPath()} has no mesh below it; a mover needs geometry")
    return np.concatenate(out)


# -- boats ---------------------------------------------------------------------------------------
@dataclass(frozen=True)
class Waves:
    """Heave amplitude (m), roll and pitch amplitudes (degrees), yaw wander (degrees), their
    periods (s) and phases (radians)."""

    bob: float = 0.04
    roll: float = 2.5
    pitch: float = 1.0
    yaw: float = 1.5
    periods: tuple[float, float, float, float] = (3.2, 4.1, 2.7, 9.0)
    phases: tuple[float, float, float, float] = (0.0, 0.0, 0.0, 0.0)


def wave_params(rng: np.random.Generator, calm: float = 1.0) -> Waves:
    """Gentle random waves (``calm`` scales the amplitudes)."""
    return Waves(bob=calm * float(rng.uniform(0.02, 0.05)), roll=calm * float(rng.uniform(1.5, 3.5)),
                 pitch=calm * float(rng.uniform(0.5, 1.5)), yaw=calm * float(rng.uniform(0.5, 2.0)),
                 periods=tuple(float(p) for p in rng.uniform([2.5, 3.0, 2.0, 7.0], [4.0, 5.0, 3.5, 12.0])),
                 phases=tuple(float(p) for p in rng.uniform(0, 2 * np.pi, 4)))


def boat_motion(frames, fps: float, start, yaw_deg: float, velocity, level: float, draft: float,
                waves: Waves = Waves()) -> RigidMotion:
    """A boat whose local origin is its hull's lowest centre (z = 0): the waterline centre, local
    (0, 0, ``draft``), drifts from ``start`` (x, y) with ``velocity`` (vx, vy m/s) at height
    ``level`` + heave, and the hull rolls, pitches and wanders in yaw about it."""
    frames = np.asarray(frames)
    t = (frames - frames[0]) / fps
    w = 2 * np.pi * t[:, None] / np.asarray(waves.periods)[None] + np.asarray(waves.phases)[None]
    s = np.sin(w)
    centre = np.column_stack([start[0] + velocity[0] * t, start[1] + velocity[1] * t, level + waves.bob * s[:, 0]])
    rotate = np.column_stack([waves.roll * s[:, 1], waves.pitch * s[:, 2], yaw_deg + waves.yaw * s[:, 3]])
    pivot = np.array([0.0, 0.0, draft])
    return RigidMotion(frames, centre - rot_xyz(rotate) @ pivot, rotate)


def draft_band(draft: float, half_length: float, half_width: float, waves: Waves) -> tuple[float, float]:
    """Closed-form range of depths below the water of any point of a flat hull bottom (local z = 0,
    |x| <= half_length, |y| <= half_width) under :func:`boat_motion`.

    The depth of bottom point (x, y) is draft cos p cos r - heave + x sin p - y cos p sin r
    (the z row of Rz Ry Rx is (-sin p, cos p sin r, cos p cos r)), bounded term by term."""
    r, p = np.radians(abs(waves.roll)), np.radians(abs(waves.pitch))
    spread = abs(waves.bob) + half_length * np.sin(p) + half_width * np.sin(r)
    return float(draft * np.cos(p) * np.cos(r) - spread), float(draft + spread)


def drift_boat(stage: Usd.Stage, prim_path: str, velocity=(0.0, 0.0), level: float | None = None,
               waves: Waves | None = None, rng: np.random.Generator | None = None) -> RigidMotion:
    """Make the boat at ``prim_path`` (placed upright with its hull bottom at its origin) drift with
    ``velocity`` (m/s) and bob on water at height ``level`` (default: where it floats now, its
    hull bottom being ``draft`` below it, given by its ``lfusd:constraint:draft`` or 0.3 m).
    Authors the motion and the boat's ``draft`` constraint (:func:`draft_band`); returns the motion."""
    from .rules import set_constraint

    prim = stage.GetPrimAtPath(prim_path)
    if not prim:
        raise LfusdError(f"no prim {prim_path} on the stage; give the path of a boat")
    pos, yaw = start_pose(prim)
    pts = _local_points(prim)
    if abs(pts[:, 2].min()) > 1e-6:
        raise LfusdError(f"boat {prim_path}'s lowest point is at local z = {pts[:, 2].min():g}, not 0; "
                         "put its origin at the bottom of its hull")
    draft_attr = prim.GetAttribute(constraint_attr("draft"))
    draft = float(np.mean(draft_attr.Get())) if draft_attr and draft_attr.HasAuthoredValue() else 0.3
    level = float(pos[2] + draft) if level is None else float(level)
    draft = level - float(pos[2])
    waves = waves if waves is not None else wave_params(rng if rng is not None else np.random.default_rng(0))
    frames, fps = _frames(stage)
    motion = boat_motion(frames, fps, pos[:2], yaw, velocity, level, draft, waves)
    author(prim, motion)
    bottom = pts[np.abs(pts[:, 2]) < 1e-6]
    lo, hi = draft_band(draft, float(np.abs(bottom[:, 0]).max()), float(np.abs(bottom[:, 1]).max()), waves)
    if lo <= 0.0:
        raise LfusdError(f"boat {prim_path} would lift out of the water (draft {draft:.2f} m, waves up to "
                         f"{draft - lo:.2f} m); calm the waves or sink it deeper")
    set_constraint(prim, "draft", (lo - 1e-3, hi + 1e-3))
    return motion


# -- cars ----------------------------------------------------------------------------------------
def drive_motion(frames, fps: float, start, yaw_deg: float, speed: float, z: float, delay: float = 0.0) -> RigidMotion:
    """Straight along the heading ``yaw_deg`` from ``start`` (x, y) at ``speed`` m/s after ``delay`` s."""
    frames = np.asarray(frames)
    t = np.maximum((frames - frames[0]) / fps - delay, 0.0)
    h = np.radians(yaw_deg)
    d = speed * t
    translate = np.column_stack([start[0] + d * np.cos(h), start[1] + d * np.sin(h), np.full(len(t), z)])
    return RigidMotion(frames, translate, np.tile([0.0, 0.0, yaw_deg], (len(t), 1)))


def make_wheel(prim: Usd.Prim, hub, radius: float) -> Usd.Prim:
    """Mark ``prim`` (a child of a car named ``wheel*``: its mesh centred on its origin, axle along
    Y) as a wheel of ``radius`` at ``hub`` (car frame); :func:`drive_car` turns it.

    Put the transform on the wheel's mesh itself rather than on an Xform above a single mesh:
    Blender's USD import merges such an Xform into its mesh, and the merged object is then known
    by the Xform's prim path only."""
    UsdGeom.Xformable(prim).AddTranslateOp(UsdGeom.XformOp.PrecisionDouble).Set(Gf.Vec3d(*[float(v) for v in hub]))
    prim.CreateAttribute(WHEEL_RADIUS, Sdf.ValueTypeNames.Double, custom=True).Set(float(radius))
    return prim


def drive_car(stage: Usd.Stage, prim_path: str, speed: float, delay: float = 0.0) -> RigidMotion:
    """Drive the car at ``prim_path`` straight along its heading (its rotateZ) at ``speed`` m/s;
    its ``wheel*`` children (see :func:`make_wheel`) roll without slipping. Returns the body motion."""
    prim = stage.GetPrimAtPath(prim_path)
    if not prim:
        raise LfusdError(f"no prim {prim_path} on the stage; give the path of a car")
    if not speed > 0:
        raise LfusdError(f"car speed {speed:g} m/s is not positive; give a speed > 0")
    pos, yaw = start_pose(prim)
    frames, fps = _frames(stage)
    motion = drive_motion(frames, fps, pos[:2], yaw, speed, float(pos[2]), delay)
    author(prim, motion)
    dist = np.linalg.norm(motion.translate[:, :2] - motion.translate[0, :2], axis=1)
    for child in prim.GetChildren():
        attr = child.GetAttribute(WHEEL_RADIUS)
        if child.GetName().startswith("wheel") and attr and attr.HasAuthoredValue():
            hub, _ = start_pose(child)
            spin = np.degrees(dist / float(attr.Get()))  # about +Y: the bottom moves backwards
            author(child, RigidMotion(frames, np.tile(hub, (len(frames), 1)),
                                      np.column_stack([np.zeros_like(spin), spin, np.zeros_like(spin)])))
    return motion


# -- rooms -----------------------------------------------------------------------------------------
def swing_motion(frames, fps: float, hinge, closed_yaw: float, open_deg: float, t_open: float, t_close: float | None,
                 duration: float = 1.5) -> RigidMotion:
    """A door turning about the vertical axis through ``hinge``: from ``closed_yaw`` by ``open_deg``
    (signed) over ``duration`` s from ``t_open`` s, and back from ``t_close`` s (None: stays open)."""
    frames = np.asarray(frames)
    t = (frames - frames[0]) / fps
    k = smootherstep((t - t_open) / duration)
    if t_close is not None:
        k = k - smootherstep((t - t_close) / duration)
    rotate = np.column_stack([np.zeros_like(t), np.zeros_like(t), closed_yaw + open_deg * k])
    return RigidMotion(frames, np.tile(np.asarray(hinge, float), (len(t), 1)), rotate)


def swing(stage: Usd.Stage, prim_path: str, open_deg: float, t_open: float, t_close: float | None = None,
          duration: float = 1.5) -> RigidMotion:
    """Swing the door at ``prim_path`` (its origin on the hinge axis, its pose now = closed)."""
    prim = stage.GetPrimAtPath(prim_path)
    if not prim:
        raise LfusdError(f"no prim {prim_path} on the stage; give the path of a door")
    pos, yaw = start_pose(prim)
    frames, fps = _frames(stage)
    motion = swing_motion(frames, fps, pos, yaw, open_deg, t_open, t_close, duration)
    author(prim, motion)
    return motion


def slide_motion(frames, fps: float, start, yaw_deg: float, offset, t0: float, duration: float,
                 t_back: float | None = None) -> RigidMotion:
    """An object sliding by ``offset`` (dx, dy) over its support from ``t0`` s for ``duration`` s
    (and back from ``t_back`` s), keeping its height and heading."""
    frames = np.asarray(frames)
    t = (frames - frames[0]) / fps
    k = smootherstep((t - t0) / duration)
    if t_back is not None:
        k = k - smootherstep((t - t_back) / duration)
    translate = np.asarray(start, float)[None] + k[:, None] * np.array([offset[0], offset[1], 0.0])[None]
    return RigidMotion(frames, translate, np.tile([0.0, 0.0, yaw_deg], (len(t), 1)))


def slide(stage: Usd.Stage, prim_path: str, offset, t0: float, duration: float, t_back: float | None = None) -> RigidMotion:
    """Slide the object at ``prim_path`` by ``offset`` (x, y metres) over its support."""
    prim = stage.GetPrimAtPath(prim_path)
    if not prim:
        raise LfusdError(f"no prim {prim_path} on the stage; give the path of an object")
    pos, yaw = start_pose(prim)
    frames, fps = _frames(stage)
    motion = slide_motion(frames, fps, pos, yaw, offset, t0, duration, t_back)
    author(prim, motion)
    return motion

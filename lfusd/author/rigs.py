"""Light-field rigs stored in USD stages.

A rig is an Xform prim (by default ``/Rigs/<name>``) whose local frame is the rig frame in
OpenCV axes (x right, y down, z forward), carrying its parameters as ``lfusd:rig:*``
attributes, with one UsdGeom.Camera child ``cam_RR_CC`` per view. Animate the rig prim's
transform to move the whole rig. Camera lenses follow USD's rule that focalLength and the
apertures are in tenths of a scene unit.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np
from pxr import Gf, Sdf, Usd, UsdGeom

from ..errors import LfusdError
from ..camera import RigSpec, View
from .stage import WorldFrame, world_frame
from .vocabulary import RIG_VIEW, rig_attr

RIGS_ROOT = "/Rigs"
# OpenCV camera axes -> USD/Blender camera axes (y up, looking down -z), both ways.
FLIP_YZ = np.diag([1.0, -1.0, -1.0, 1.0])

_FIELDS: dict[str, Sdf.ValueTypeName] = {
    "rows": Sdf.ValueTypeNames.Int,
    "cols": Sdf.ValueTypeNames.Int,
    "baseline": Sdf.ValueTypeNames.Double,
    "focal_length_mm": Sdf.ValueTypeNames.Double,
    "sensor_mm": Sdf.ValueTypeNames.Double,
    "width": Sdf.ValueTypeNames.Int,
    "height": Sdf.ValueTypeNames.Int,
    "at": Sdf.ValueTypeNames.Double3,
    "look_at": Sdf.ValueTypeNames.Double3,
    "spacing": Sdf.ValueTypeNames.Token,
    "layout": Sdf.ValueTypeNames.Token,
    "radius": Sdf.ValueTypeNames.Double,
    "axes": Sdf.ValueTypeNames.Token,
}


def camera_name(view: View) -> str:
    return f"cam_{view[0]:02d}_{view[1]:02d}"


def _gf(m: np.ndarray) -> Gf.Matrix4d:
    # USD matrices act on row vectors: store the transpose of a column-vector pose.
    return Gf.Matrix4d(*np.asarray(m, float).T.ravel().tolist())


def _np(m: Gf.Matrix4d) -> np.ndarray:
    return np.array(m, dtype=np.float64).T


def _rig_in_stage(spec: RigSpec, world: WorldFrame) -> np.ndarray:
    """The rig prim's transform in the stage's axes and units (column vectors).

    ``spec.at`` and ``spec.look_at`` are metres along the stage's own axes: they are mapped into
    lfusd's world, where the pose is built with world +Z (the stage's up axis) as up, and the
    pose is mapped back, so that ``world.pose`` of the result is that world pose exactly."""
    r = world.rotation
    in_world = replace(spec, at=tuple(r @ np.asarray(spec.at, float)), look_at=tuple(r @ np.asarray(spec.look_at, float)))
    pose = in_world.rig_to_world()
    local = np.eye(4)
    local[:3, :3] = r.T @ pose[:3, :3]
    local[:3, 3] = r.T @ pose[:3, 3] / world.meters_per_unit
    return local


def add_rig(stage: Usd.Stage, spec: RigSpec, parent: str = RIGS_ROOT) -> Usd.Prim:
    """Author ``spec`` as a rig prim with one camera per view; refuse a name already used.

    ``spec.at`` / ``spec.look_at`` are metres along the stage's axes and the rig's up is the
    stage's up axis; transforms, lenses and clipping are authored in scene units."""
    if spec.name in rigs(stage):
        raise LfusdError(f"the stage already has a rig named {spec.name!r}; choose another --name")
    world = world_frame(stage)
    mpu = world.meters_per_unit
    if not stage.GetPrimAtPath(parent):
        UsdGeom.Scope.Define(stage, parent)
    rig = UsdGeom.Xform.Define(stage, Sdf.Path(parent).AppendChild(spec.name))
    rig.AddTransformOp().Set(_gf(_rig_in_stage(spec, world)))
    prim = rig.GetPrim()
    for key, vtype in _FIELDS.items():
        value = getattr(spec, key)
        if value is None:
            continue
        prim.CreateAttribute(rig_attr(key), vtype, custom=True).Set(Gf.Vec3d(*value) if vtype == Sdf.ValueTypeNames.Double3 else value)
    lens = 1.0 / (100.0 * mpu)  # millimetres -> tenths of a scene unit
    for view in spec.views:
        cam = UsdGeom.Camera.Define(stage, rig.GetPath().AppendChild(camera_name(view)))
        cam.CreateFocalLengthAttr(spec.focal_length_mm * lens)
        cam.CreateHorizontalApertureAttr(spec.sensor_mm * lens)
        cam.CreateVerticalApertureAttr(spec.sensor_mm * spec.height / spec.width * lens)
        cam.CreateProjectionAttr(UsdGeom.Tokens.perspective)
        cam.CreateClippingRangeAttr(Gf.Vec2f(0.01 / mpu, 1.0e4 / mpu))
        local = spec.view_in_rig(view) @ FLIP_YZ
        local[:3, 3] /= mpu
        cam.AddTransformOp().Set(_gf(local))
        cam.GetPrim().CreateAttribute(RIG_VIEW, Sdf.ValueTypeNames.Int2, custom=True).Set(Gf.Vec2i(*view))
    return prim


@dataclass(frozen=True)
class StageRig:
    """A rig read back from a stage: its spec and the camera prim of every view."""

    spec: RigSpec
    prim_path: str
    cameras: dict[View, str]

    def cam_to_world(self, stage: Usd.Stage, view: View, frame: float) -> np.ndarray:
        """4x4 OpenCV camera-to-world pose in metres at ``frame``, from the stage's transforms."""
        cam = stage.GetPrimAtPath(self.cameras[view])
        return world_frame(stage).pose(UsdGeom.Xformable(cam).ComputeLocalToWorldTransform(Usd.TimeCode(frame))) @ FLIP_YZ


def rigs(stage: Usd.Stage) -> dict[str, StageRig]:
    """Every lfusd rig on the stage, by name."""
    out: dict[str, StageRig] = {}
    for prim in stage.Traverse():
        if not prim.HasAttribute(rig_attr("rows")):
            continue
        values = {}
        for key in _FIELDS:
            attr = prim.GetAttribute(rig_attr(key))
            if attr and attr.HasAuthoredValue():
                v = attr.Get()
                values[key] = tuple(float(x) for x in v) if key in ("at", "look_at") else v
        try:
            spec = RigSpec(name=prim.GetName(), **values)
        except TypeError as e:
            raise LfusdError(f"rig {prim.GetPath()} has malformed lfusd:rig attributes ({e}); re-add it with 'lfusd rig add'") from None
        cams: dict[View, str] = {}
        for child in prim.GetChildren():
            attr = child.GetAttribute(RIG_VIEW)
            if child.IsA(UsdGeom.Camera) and attr and attr.HasAuthoredValue():
                v = attr.Get()
                cams[(int(v[0]), int(v[1]))] = str(child.GetPath())
        missing = [v for v in spec.views if v not in cams]
        if missing:
            raise LfusdError(f"rig {prim.GetPath()} lacks the camera of view {missing[0]}; re-add it with 'lfusd rig add'")
        if prim.GetName() in out:
            raise LfusdError(f"the stage has two rigs named {prim.GetName()!r} ({out[prim.GetName()].prim_path}, {prim.GetPath()}); rename one")
        out[prim.GetName()] = StageRig(spec, str(prim.GetPath()), cams)
    return out


def select_rigs(stage: Usd.Stage, name: str | None, stage_path: str) -> list[StageRig]:
    """The rigs that ``--rig NAME|all`` names; the only rig when NAME is omitted."""
    found = rigs(stage)
    if not found:
        raise LfusdError(f"stage {stage_path} has no light-field rig; add one with 'lfusd rig add {stage_path} --name main'")
    if name in (None, ""):
        if len(found) > 1:
            raise LfusdError(f"stage {stage_path} has {len(found)} rigs ({', '.join(sorted(found))}); choose one with --rig NAME or --rig all")
        return list(found.values())
    if name == "all":
        return [found[k] for k in sorted(found)]
    if name not in found:
        raise LfusdError(f"stage {stage_path} has no rig named {name!r}; its rigs are: {', '.join(sorted(found))}")
    return [found[name]]

"""Light-field rigs stored in USD stages.

A rig is an Xform prim (by default ``/Rigs/<name>``) whose local frame is the rig frame in
OpenCV axes (x right, y down, z forward), carrying its parameters as ``lfusd:rig:*``
attributes, with one UsdGeom.Camera child ``cam_RR_CC`` per view. Animate the rig prim's
transform to move the whole rig. Camera lenses follow USD's rule that focalLength and the
apertures are in tenths of a scene unit.
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from pathlib import Path

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


def _camera_prim(stage: Usd.Stage, prim_path: str) -> UsdGeom.Camera:
    prim = stage.GetPrimAtPath(prim_path) if Sdf.Path.IsValidPathString(prim_path) else None
    if not prim or not prim.IsA(UsdGeom.Camera):
        cams = [str(p.GetPath()) for p in stage.Traverse() if p.IsA(UsdGeom.Camera) and not p.HasAttribute(RIG_VIEW)]
        what = "is not a UsdGeom.Camera" if prim else "does not exist"
        raise LfusdError(f"--from-camera {prim_path} {what} on the stage; "
                         + (f"its cameras are: {', '.join(cams[:8])}" if cams else "the stage has no camera of its own, so place the rig with --at and --look-at"))
    cam = UsdGeom.Camera(prim)
    if cam.GetProjectionAttr().Get() not in (None, UsdGeom.Tokens.perspective):
        raise LfusdError(f"camera {prim_path} is orthographic; a light-field rig needs a perspective camera, so place the rig with --at and --look-at")
    return cam


def _time_varying(prim: Usd.Prim) -> bool:
    """Whether the prim's world transform may change over time (its own ops or an ancestor's)."""
    while prim and not prim.IsPseudoRoot():
        x = UsdGeom.Xformable(prim)
        if x and x.TransformMightBeTimeVarying():
            return True
        prim = prim.GetParent()
    return False


def camera_pose(stage: Usd.Stage, prim_path: str, time=Usd.TimeCode.Default()) -> np.ndarray:
    """The 4x4 OpenCV camera-to-world pose (lfusd's world, metres) of a stage camera; any scale
    in its transform is left out (the nearest rotation)."""
    cam = _camera_prim(stage, prim_path)
    pose = world_frame(stage).pose(cam.ComputeLocalToWorldTransform(time)) @ FLIP_YZ
    u, _, vt = np.linalg.svd(pose[:3, :3])
    pose[:3, :3] = u @ vt
    return pose


def camera_lens(stage: Usd.Stage, prim_path: str, time=Usd.TimeCode.Default()) -> tuple[float, float, float]:
    """(focal length, horizontal aperture, vertical aperture) of a stage camera in millimetres:
    USD states them in tenths of a scene unit."""
    cam = _camera_prim(stage, prim_path)
    to_mm = 100.0 * world_frame(stage).meters_per_unit
    return tuple(float(a.Get(time)) * to_mm for a in (cam.GetFocalLengthAttr(), cam.GetHorizontalApertureAttr(), cam.GetVerticalApertureAttr()))


def add_rig_at_camera(stage: Usd.Stage, spec: RigSpec, prim_path: str, parent: str = RIGS_ROOT) -> tuple[Usd.Prim, RigSpec]:
    """Author ``spec`` (grid, baseline, spacing, layout, resolution) as a rig whose centre view is
    the stage's own camera ``prim_path``: its pose at every frame it moves in, its focal length
    and horizontal aperture (read at the stage's first frame; a rig has one lens). ``spec``'s
    pose and lens are replaced; returns the rig prim and the spec authored."""
    from .stage import frame_range

    world = world_frame(stage)
    first, last = frame_range(stage)
    t0 = Usd.TimeCode(first)
    focal, h_ap, _ = camera_lens(stage, prim_path, t0)
    if not (focal > 0 and h_ap > 0):
        raise LfusdError(f"camera {prim_path} has focal length {focal:g} mm and aperture {h_ap:g} mm; author positive values on it first")
    pose = camera_pose(stage, prim_path, t0)
    r = world.rotation
    at = r.T @ pose[:3, 3]  # metres along the stage's axes, as --at
    spec = replace(spec, focal_length_mm=focal, sensor_mm=h_ap, at=tuple(float(x) for x in at),
                   look_at=tuple(float(x) for x in at + r.T @ pose[:3, 2]))
    prim = add_rig(stage, spec, parent)
    centre_in_rig = np.linalg.inv(spec.view_in_rig(spec.centre_view))

    def local(t) -> Gf.Matrix4d:  # the rig prim's transform that puts the centre view at the camera
        rig_to_world = camera_pose(stage, prim_path, t) @ centre_in_rig
        m = np.eye(4)
        m[:3, :3] = r.T @ rig_to_world[:3, :3]
        m[:3, 3] = r.T @ rig_to_world[:3, 3] / world.meters_per_unit
        return _gf(m)

    op = UsdGeom.Xformable(prim).GetOrderedXformOps()[0]
    op.Set(local(t0))
    if _time_varying(stage.GetPrimAtPath(prim_path)):
        for f in range(first, last + 1):
            op.Set(local(Usd.TimeCode(f)), Usd.TimeCode(f))
    return prim, spec


def add_rig_to_file(stage_path: str | Path, out: str | Path | None = None, *, name: str = "main",
                    grid: tuple[int, int] | None = None, baseline: float | None = None, focal_length_mm: float | None = None,
                    sensor_mm: float | None = None, resolution: tuple[int, int] | None = None, at=None, look_at=None,
                    spacing: str | None = None, layout: str | None = None, radius: float | None = None, axes: str | None = None,
                    from_camera: str | None = None, force: bool = False) -> tuple[RigSpec, str]:
    """`lfusd rig add`: author a rig into the stage file ``stage_path`` (into a new layer ``out``
    over it when given) and save; returns the rig as authored and the file written.

    None takes :class:`RigSpec`'s default; the pose is then stated in lfusd's world (Z up) and
    turned into the stage's axes, so the default rig stands upright on any stage. ``at`` and
    ``look_at`` are metres along the stage's own axes. ``from_camera``: centre the rig on that
    camera prim (:func:`add_rig_at_camera`), its aspect giving the height when ``resolution`` is
    None. ``force`` lifts the size limits (:func:`lfusd.camera.check_rig_size`)."""
    from .stage import usd_warnings

    with usd_warnings():  # what pxr posts while authoring and saving: one line each, not its raw output
        return _add_rig_to_file(stage_path, out, name=name, grid=grid, baseline=baseline, focal_length_mm=focal_length_mm,
                                sensor_mm=sensor_mm, resolution=resolution, at=at, look_at=look_at, spacing=spacing, layout=layout,
                                radius=radius, axes=axes, from_camera=from_camera, force=force)


def _add_rig_to_file(stage_path, out, *, name, grid, baseline, focal_length_mm, sensor_mm, resolution, at, look_at, spacing,
                     layout, radius, axes, from_camera, force) -> tuple[RigSpec, str]:
    from ..camera import check_rig_size
    from .stage import open_for_edit, save_stage

    d = RigSpec()
    if from_camera is not None:
        given = [o for o, v in (("--at", at), ("--look-at", look_at), ("--focal-length", focal_length_mm), ("--sensor", sensor_mm)) if v is not None]
        if given:
            raise LfusdError(f"--from-camera takes the pose and lens from the camera; drop {given[0]}")
    rows, cols = grid or (d.rows, d.cols)
    check_rig_size((rows, cols), resolution or (d.width, d.height), force)  # a million cameras take hours to author: refuse first
    layout = layout or d.layout
    axes = axes or ("converge" if layout == "sphere" else "parallel")
    stage = open_for_edit(stage_path, out)
    width, height = resolution or (d.width, d.height)
    if from_camera is not None and resolution is None:
        _, h_ap, v_ap = camera_lens(stage, from_camera)
        height = max(1, round(width * v_ap / h_ap)) if h_ap > 0 and v_ap > 0 else height
    turn = world_frame(stage).rotation.T
    at = at if at is not None else tuple(float(x) for x in turn @ d.at)
    look_at = look_at if look_at is not None else tuple(float(x) for x in turn @ d.look_at)
    spec = RigSpec(
        name=name, rows=rows, cols=cols, baseline=d.baseline if baseline is None else baseline,
        focal_length_mm=focal_length_mm or d.focal_length_mm, sensor_mm=sensor_mm or d.sensor_mm, width=width, height=height,
        at=at, look_at=look_at, spacing=spacing or d.spacing, layout=layout, radius=radius, axes=axes,
    )
    if from_camera is not None:
        _, spec = add_rig_at_camera(stage, spec, from_camera)
    else:
        add_rig(stage, spec)
    target = str(out or stage_path)
    save_stage(stage, target)
    return spec, target


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
        new = f"{Path(stage_path).stem}_rig.usda"
        cams = [str(p.GetPath()) for p in stage.Traverse() if p.IsA(UsdGeom.Camera)]
        hint = f"'lfusd rig add {stage_path} -o {new} --from-camera {cams[0]}'" if cams else f"'lfusd rig add {stage_path} -o {new} --name main'"
        raise LfusdError(f"stage {stage_path} has no light-field rig; add one in a new layer over it with {hint}, then render {new}")
    if name in (None, ""):
        if len(found) > 1:
            raise LfusdError(f"stage {stage_path} has {len(found)} rigs ({', '.join(sorted(found))}); choose one with --rig NAME or --rig all")
        return list(found.values())
    if name == "all":
        return [found[k] for k in sorted(found)]
    if name not in found:
        raise LfusdError(f"stage {stage_path} has no rig named {name!r}; its rigs are: {', '.join(sorted(found))}")
    return [found[name]]

"""The arrangements a study compares, and the distinct cameras they need.

An arrangement is one combination of baseline, spacing, layout and axes; a candidate is an
arrangement placed at one study position (a rig of the stage: its frame, lens and look-at
point), with the study's grid and resolution. Cameras are compared in the rig's own frame: two
views with the same rig-local pose (rounded to 1 nm and 1e-9) and the same lens and resolution
are one camera, rendered once however many candidates hold it (every spacing shares its first
gap, so all spacings of one baseline share the centre 3x3 views; a plane and a sphere share the
centre view, ...). The distinct cameras of a position are authored, with lfusd's rig authoring,
as one 1xN rig (the position's *union rig*) whose camera k is placed at its own pose.
"""

from __future__ import annotations

import hashlib
import logging
from dataclasses import dataclass, replace

import numpy as np

from ..camera import RigSpec, View
from ..errors import LfusdError

log = logging.getLogger(__name__)

POSE_DECIMALS = 9  # 1 nm in metres, 1e-9 in rotation entries: far below any pixel


@dataclass(frozen=True)
class Arrangement:
    """How the cameras are arranged, independent of where the rig stands."""

    baseline: float
    spacing: str
    layout: str
    axes: str

    @property
    def name(self) -> str:
        """A USD prim name: ``b0p125_uniform_plane_parallel``."""
        return f"b{self.baseline:g}".replace(".", "p").replace("-", "m") + f"_{self.spacing}_{self.layout}_{self.axes}"

    def to_dict(self) -> dict:
        return {"baseline": self.baseline, "spacing": self.spacing, "layout": self.layout, "axes": self.axes}


@dataclass(frozen=True)
class Candidate:
    """An arrangement at one position: its rig (study grid and resolution) and the id of each view's camera."""

    arrangement: Arrangement
    position: str
    spec: RigSpec
    cameras: tuple[str, ...]  # camera id of every view, in spec.views order (row-major)

    @property
    def name(self) -> str:
        return f"{self.position}_{self.arrangement.name}"


def arrangements(baselines, spacings, layouts, axes) -> list[Arrangement]:
    """Every combination, in the order given (baseline slowest)."""
    return [Arrangement(float(b), s, lay, ax) for b in baselines for s in spacings for lay in layouts for ax in axes]


def candidate_spec(base: RigSpec, arrangement: Arrangement, grid: tuple[int, int], resolution: tuple[int, int]) -> RigSpec:
    """The base rig (position, look-at point, lens, sphere radius) with the arrangement, grid and
    resolution of the study; LfusdError when the combination is impossible (a sphere wider than
    a hemisphere)."""
    a = arrangement
    return replace(base, name=f"c_{a.name}", rows=grid[0], cols=grid[1], width=resolution[0], height=resolution[1],
                   baseline=a.baseline, spacing=a.spacing, layout=a.layout, axes=a.axes)


def camera_id(spec: RigSpec, view: View) -> str:
    """The identity of a view's camera: its rig-local pose (rounded) with the lens and resolution."""
    pose = np.round(spec.view_in_rig(view), POSE_DECIMALS) + 0.0  # + 0.0 turns -0.0 into 0.0
    lens = np.array([spec.focal_length_mm, spec.sensor_mm, spec.width, spec.height], np.float64)
    return hashlib.sha1(pose.astype("<f8").tobytes() + lens.astype("<f8").tobytes()).hexdigest()[:16]


@dataclass
class Union:
    """The distinct cameras of one position: ids in rendering order and each one's rig-local pose."""

    position: str
    ids: list[str]
    poses: dict[str, np.ndarray]

    def index(self) -> dict[str, int]:
        return {c: k for k, c in enumerate(self.ids)}


def build(bases: dict[str, RigSpec], arrs: list[Arrangement], grid, resolution) -> tuple[list[Candidate], list[tuple[str, str]], dict[str, Union]]:
    """(candidates, skipped (name, reason), union of cameras per position) for the given base rigs."""
    candidates, skipped, unions = [], [], {}
    for position, base in bases.items():
        union = unions.setdefault(position, Union(position, [], {}))
        for a in arrs:
            try:
                spec = candidate_spec(base, a, grid, resolution)
            except LfusdError as e:
                skipped.append((f"{position}_{a.name}", str(e).split(";")[0]))
                continue
            ids = []
            for view in spec.views:
                cid = camera_id(spec, view)
                if cid not in union.poses:
                    union.ids.append(cid)
                    union.poses[cid] = spec.view_in_rig(view)
                ids.append(cid)
            candidates.append(Candidate(a, position, spec, tuple(ids)))
    for name, why in skipped:
        log.warning("candidate %s is impossible (%s); skipping it", name, why)
    if not candidates:
        raise LfusdError("no candidate arrangement is possible (every sphere spans more than a hemisphere); use smaller --baselines or --layout plane")
    return candidates, skipped, unions


def union_rig_name(position: str) -> str:
    return f"study_{position}"


def author_union(stage, base_prim_path: str, spec: RigSpec, union: Union, frames: list[int]):
    """Author ``union`` as a 1xN rig beside the base rig, in the base rig's frame (its local
    transform copied, at every frame the render may ask for when it is animated), camera k at
    the rig-local pose of ``union.ids[k]``."""
    from pxr import Gf, Sdf, Usd, UsdGeom

    from ..author.rigs import FLIP_YZ, add_rig, camera_name
    from ..author.stage import world_frame

    name = union_rig_name(union.position)
    parent = Sdf.Path(base_prim_path).GetParentPath()
    uspec = replace(spec, name=name, rows=1, cols=len(union.ids), spacing="uniform", layout="plane", axes="parallel", radius=None)
    prim = add_rig(stage, uspec, parent=str(parent))
    base = UsdGeom.Xformable(stage.GetPrimAtPath(base_prim_path))
    op = UsdGeom.Xformable(prim).GetOrderedXformOps()[0]
    if base.TransformMightBeTimeVarying():
        for f in range(min(frames) - 1, max(frames) + 2):  # t-1 and t+1 too: the motion passes read them
            op.Set(base.GetLocalTransformation(Usd.TimeCode(f)), Usd.TimeCode(f))
    else:
        op.Set(base.GetLocalTransformation(Usd.TimeCode.Default()))
    mpu = world_frame(stage).meters_per_unit
    for k, cid in enumerate(union.ids):
        local = union.poses[cid] @ FLIP_YZ
        local[:3, 3] /= mpu
        cam = UsdGeom.Xformable(stage.GetPrimAtPath(prim.GetPath().AppendChild(camera_name((0, k)))))
        cam.GetOrderedXformOps()[0].Set(Gf.Matrix4d(*np.asarray(local, float).T.ravel().tolist()))
    return prim

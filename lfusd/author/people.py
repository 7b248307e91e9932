"""Putting people on a stage: a walking or running person along a path over supporting surfaces.

The path (points in metres along the stage's horizontal axes: X, Y on a Z-up stage, X, Z on a
Y-up one; :func:`path_axes`) is worked in lfusd's world (Z up, metres) and the person authored
into the stage's axes, units and parent transforms. It has its corners rounded with circular fillets, so the
person turns smoothly; the person's root follows the path from ``start``, speeding up from rest
to the given speed and slowing to a stop at the path's end (standing at the first point before,
at the last point after); its height is the supporting surface under it found by ray casting
down (Open3D) onto labelled support surfaces (lfusd.author.geometry.StageGeometry meshes), and its
limbs come from lfusd.author.gait with feet planted on those surfaces. Support and water classes come
from the rulebook's ``person`` rule (lfusd.author.rules). A path whose person would be over
water, or over no support at all, at some frame is refused naming that frame; the finished
person is checked with the rulebook at every frame.
"""

from __future__ import annotations

import logging
import os
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from pxr import Sdf, Usd, UsdGeom, UsdSemantics, UsdShade, UsdSkel

from . import gait as _gait
from . import human as _human
from ..errors import LfusdError
from .geometry import StageGeometry
from .labels import TAXONOMY, class_label, labelled_ancestor, set_class_label
from .stage import frame_range, world_frame
from .vocabulary import ANY, GROUND, WATER

log = logging.getLogger(__name__)

PEOPLE_SCOPE = "/World/People"
FILLET_RADIUS = 1.0  # metres: how tight a person turns at a path corner


def parse_points(texts: list[str]) -> np.ndarray:
    """Parse ``['X,Y', ...]`` into an (N, 2) array; refuses fewer than two points."""
    pts = []
    for t in texts:
        parts = t.replace(" ", "").split(",")
        try:
            if len(parts) != 2:
                raise ValueError
            pts.append((float(parts[0]), float(parts[1])))
        except ValueError:
            raise LfusdError(f"path point {t!r} is not X,Y; write points like 0,0 4.5,2") from None
    return check_points(pts)


def check_points(points) -> np.ndarray:
    pts = np.asarray(points, dtype=np.float64).reshape(-1, 2) if len(points) else np.zeros((0, 2))
    if len(pts) < 2:
        raise LfusdError(f"a path needs at least two points, got {len(pts)}; give --path X,Y X,Y ...")
    if not np.all(np.isfinite(pts)):
        raise LfusdError("path points must be finite numbers; fix the --path values")
    keep = np.concatenate([[True], np.linalg.norm(np.diff(pts, axis=0), axis=1) > 1e-6])
    pts = pts[keep]
    if len(pts) < 2:
        raise LfusdError("the path's points are all the same; give at least two distinct points")
    return pts


class SmoothPath:
    """A polyline with corners rounded by circular fillets, parametrised by arc length."""

    def __init__(self, points: np.ndarray, radius: float = FILLET_RADIUS, step: float = 0.02):
        pts = np.asarray(points, float)
        dense = [pts[0]]
        for i in range(1, len(pts) - 1):
            a, b, c = pts[i - 1], pts[i], pts[i + 1]
            d1, d2 = (b - a) / np.linalg.norm(b - a), (c - b) / np.linalg.norm(c - b)
            turn = np.arctan2(d1[0] * d2[1] - d1[1] * d2[0], d1 @ d2)
            if abs(turn) < 1e-6:
                dense.append(b)
                continue
            t = min(radius * np.tan(abs(turn) / 2), 0.5 * np.linalg.norm(b - a), 0.5 * np.linalg.norm(c - b))
            r = t / np.tan(abs(turn) / 2)
            p0 = b - d1 * t
            normal = np.array([-d1[1], d1[0]]) * np.sign(turn)  # towards the arc's centre
            centre = p0 + normal * r
            a0 = np.arctan2(*(p0 - centre)[::-1])
            n = max(2, int(np.ceil(abs(turn) * r / step)) + 1)
            ang = a0 + np.sign(turn) * np.linspace(0, abs(turn), n)
            dense.extend(centre + r * np.column_stack([np.cos(ang), np.sin(ang)]))
        dense.append(pts[-1])
        dense = np.array(dense)
        # Resample straight runs too, so headings interpolate smoothly everywhere.
        seg = np.linalg.norm(np.diff(dense, axis=0), axis=1)
        keep = np.concatenate([[True], seg > 1e-9])
        dense = dense[keep]
        s = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(dense, axis=0), axis=1))])
        self.length = float(s[-1])
        self.s = np.linspace(0.0, self.length, max(2, int(np.ceil(self.length / step)) + 1))
        self.xy = np.column_stack([np.interp(self.s, s, dense[:, 0]), np.interp(self.s, s, dense[:, 1])])
        d = np.gradient(self.xy, self.s, axis=0)
        self.heading = np.unwrap(np.arctan2(d[:, 1], d[:, 0]))

    def at(self, s) -> tuple[np.ndarray, np.ndarray]:
        """(xy (N, 2), heading (N,)) at arc lengths ``s``; straight-line extrapolation beyond the ends."""
        s = np.atleast_1d(np.asarray(s, float))
        xy = np.column_stack([np.interp(s, self.s, self.xy[:, 0]), np.interp(s, self.s, self.xy[:, 1])])
        h = np.interp(s, self.s, self.heading)
        for mask, s0, hh in ((s < 0, 0.0, self.heading[0]), (s > self.length, self.length, self.heading[-1])):
            if mask.any():
                xy[mask] += np.outer(s[mask] - s0, [np.cos(hh), np.sin(hh)])
        return xy, h


class SupportSurfaces:
    """Ray casting down onto a stage's labelled support and water surfaces at one time."""

    def __init__(self, stage: Usd.Stage, time: float, support=GROUND, water=WATER,
                 geometry: StageGeometry | None = None):
        import open3d as o3d

        geometry = geometry or StageGeometry(stage)
        self.scene = o3d.t.geometry.RaycastingScene()
        self.info: list[tuple[str, str]] = []
        self.top = -np.inf
        wanted = set(support) | set(water)
        self.water = set(water)
        for prim in geometry.gprims:
            owner = labelled_ancestor(prim)
            label = class_label(owner) if owner else ""
            if label not in wanted:
                continue
            m = geometry.mesh(prim, time)
            if len(m.triangles) == 0:
                continue
            self.scene.add_triangles(m.vertices.astype(np.float32), m.triangles.astype(np.uint32))
            self.info.append((str(owner.GetPath()), label))
            self.top = max(self.top, float(m.vertices[:, 2].max()))
        if not self.info:
            raise LfusdError(
                "the stage has no surfaces labelled as support (" + ", ".join(support) + "); "
                "name the prims a person walks on with --ground PRIM (lfusd.author.labels.set_class_label from Python)"
            )

    def cast(self, xy: np.ndarray) -> tuple[np.ndarray, list[tuple[str, str] | None]]:
        """Height of the topmost support/water surface under each (x, y), NaN where none, and its owner."""
        import open3d as o3d

        xy = np.asarray(xy, float).reshape(-1, 2)
        rays = np.zeros((len(xy), 6), np.float32)
        rays[:, :2] = xy
        rays[:, 2] = self.top + 1.0
        rays[:, 5] = -1.0
        ans = self.scene.cast_rays(o3d.core.Tensor(rays))
        t = ans["t_hit"].numpy().astype(np.float64)
        gid = ans["geometry_ids"].numpy()
        z = np.where(np.isfinite(t), self.top + 1.0 - t, np.nan)
        owners = [self.info[g] if np.isfinite(tt) else None for g, tt in zip(gid, t)]
        return z, owners

    def ground(self, xy: np.ndarray) -> np.ndarray:
        """Surface height under each point; where there is none, the nearest point's that has one."""
        z, _ = self.cast(xy)
        bad = ~np.isfinite(z)
        if bad.all():
            return np.zeros(len(z))
        if bad.any():
            good = np.nonzero(~bad)[0]
            nearest = good[np.argmin(np.abs(np.nonzero(bad)[0][:, None] - good[None]), axis=1)]
            z[bad] = z[nearest]
        return z


def path_axes(wf) -> np.ndarray:
    """2x2 map of path points (metres along the stage's horizontal axes: X and Y on a Z-up
    stage, X and Z on a Y-up one) to lfusd's world X, Y (lfusd.author.stage.WorldFrame); its
    own inverse."""
    return np.diag([1.0, -1.0]) if wf.up_axis == "Y" else np.eye(2)


def person_surfaces(stage: Usd.Stage) -> tuple[tuple[str, ...], tuple[str, ...]]:
    """(classes a person stands on, classes it must never stand on): the rulebook's ``person``
    rule (default rulebook, overridden by the stage's class rules); GROUND and WATER where it is off."""
    from . import rules as constraints

    rules = dict(constraints.DEFAULT_RULES.get("person", {}))
    rules.update(constraints.stage_class_rules(stage).get("person", {}))
    return tuple(rules.get("on") or GROUND), tuple(rules.get("not_on") or WATER)


def _flight_gap(stage: Usd.Stage, prim: Usd.Prim, frames: np.ndarray, surfaces: "SupportSurfaces") -> float:
    """Largest height of the person's lowest point above the surface under it (a run's flight)."""
    geo = StageGeometry(stage)
    mine = [g for g in geo.gprims if g.GetPath().HasPrefix(prim.GetPath())]
    gap = 0.0
    for f in frames:
        v = np.concatenate([geo.mesh(g, float(f)).vertices for g in mine])
        low = v[np.argmin(v[:, 2])]
        z, _ = surfaces.cast(low[None, :2])
        if np.isfinite(z[0]):
            gap = max(gap, float(low[2] - z[0]))
    return gap


PROGRESS_EVERY_S = 5.0  # the rulebook's frames are reported at most this often (a large set takes minutes)


def _rulebook_violations(stage: Usd.Stage, prim: Usd.Prim, progress=None) -> list[str]:
    """Lines of the rulebook's violations (every frame) that concern ``prim``; ``progress(what)``
    hears which frame the check is at, every :data:`PROGRESS_EVERY_S` seconds."""
    import time

    from .rules import Checker

    first, last = frame_range(stage)
    said = [time.monotonic()]

    def at(frame: int) -> None:
        if progress is not None and time.monotonic() - said[0] >= PROGRESS_EVERY_S:
            said[0] = time.monotonic()
            progress(f"checking the stage's rules: frame {frame} of {first}-{last}")

    me = str(prim.GetPath())
    return [v.line() for v in Checker(stage).check(progress=at) if v.prim_path == me or me in v.detail]


# A character's legs (hips to ankles) must point down within this angle of the up axis.
_UPRIGHT_DEG = 35.0
# Statures accepted for a user's character, metres (outside: almost surely wrong units).
_CHARACTER_HEIGHT = (0.3, 3.0)


@dataclass
class Character:
    """A user's UsdSkel character file, read and checked (see :func:`read_character`).

    ``K`` maps the file's world (its own axes and units, every transform above the SkelRoot
    included) into the character frame: Z up, facing +Y, metres, origin on the ground between
    the ankles; ``rig`` is its skeleton with joints recognised by lfusd.author.skeletons."""

    path: Path
    stage: Usd.Stage
    skel: UsdSkel.Skeleton
    root: Usd.Prim
    K: np.ndarray
    rig: _gait.CharacterRig
    height: float  # bind-pose mesh, sole to top, metres


def _col(usd_matrix) -> np.ndarray:
    return np.array(usd_matrix, dtype=np.float64).T


def _open_character(character: str | Path):
    """(stage, skeleton, SkelRoot prim, skinned meshes) of a user's character file, or a one-line LfusdError."""
    cpath = Path(character)
    if not cpath.is_file():
        raise LfusdError(f"character {cpath} does not exist; give the path of a UsdSkel .usd/.usda/.usdc file")
    try:
        cstage = Usd.Stage.Open(str(cpath.resolve()))
    except Exception:
        cstage = None
    if cstage is None:
        raise LfusdError(f"character {cpath} is not a readable USD file; fix or re-export it")
    skels = [p for p in cstage.Traverse() if p.IsA(UsdSkel.Skeleton)]
    if not skels:
        raise LfusdError(f"character {cpath} has no UsdSkel Skeleton; give a file with a SkelRoot, a Skeleton and a skinned mesh")
    roots = [UsdSkel.Root.Find(p) for p in skels]
    if not any(roots):
        raise LfusdError(f"character {cpath}'s skeleton {skels[0].GetPath()} is not under a SkelRoot; wrap it in one")
    for p in skels:
        try:
            _gait.check_joint_paths(UsdSkel.Skeleton(p))
        except LfusdError as e:
            raise LfusdError(f"character {cpath}: {e}") from None
    # The skeleton that skins a mesh (UsdSkel's own binding resolution), the first found.
    cache = UsdSkel.Cache()
    for root in dict.fromkeys(r.GetPrim() for r in roots if r):
        cache.Populate(UsdSkel.Root(root), Usd.PrimDefaultPredicate)
        for binding in cache.ComputeSkelBindings(UsdSkel.Root(root), Usd.PrimDefaultPredicate):
            meshes = [t for t in binding.GetSkinningTargets() if t.GetPrim().IsA(UsdGeom.Mesh)]
            if meshes:
                return cstage, binding.GetSkeleton(), root, meshes
    raise LfusdError(
        f"character {cpath} has no mesh bound to its skeleton {skels[0].GetPath()}; bind one under the SkelRoot "
        "with UsdSkel.BindingAPI (skel:skeleton, primvars:skel:jointIndices and jointWeights)"
    )


def _bind_points(cpath: Path, skins) -> np.ndarray:
    """Every skinned mesh's bind-pose points in the skeleton's space (geomBindTransform applied)."""
    out = []
    for skin in skins:
        prim = skin.GetPrim()
        if skin.HasBlendShapes():
            raise LfusdError(f"character {cpath}'s mesh {prim.GetPath()} has UsdSkel blend shapes, which lfusd does not evaluate; "
                             "re-export the character without blend shapes (morph targets)")
        pts = UsdGeom.Mesh(prim).GetPointsAttr().Get(Usd.TimeCode.EarliestTime())
        if pts is None or len(pts) == 0:
            raise LfusdError(f"character {cpath}'s mesh {prim.GetPath()} has no points; author its points attribute")
        geom_bind = _col(skin.GetGeomBindTransform(Usd.TimeCode.EarliestTime()))
        pts = np.array(pts, dtype=np.float64)
        out.append(pts @ geom_bind[:3, :3].T + geom_bind[:3, 3])
    return np.concatenate(out)


def _bind_weights(skel: UsdSkel.Skeleton, skins) -> np.ndarray:
    """(points, joints) skin weights of every skinned mesh's points, in the skeleton's joint order."""
    joints = [str(j) for j in skel.GetJointsAttr().Get() or []]
    index = {j: i for i, j in enumerate(joints)}
    out = []
    for skin in skins:
        n = len(UsdGeom.Mesh(skin.GetPrim()).GetPointsAttr().Get(Usd.TimeCode.EarliestTime()) or [])
        dense = np.zeros((n, len(joints)))
        got = skin.ComputeVaryingJointInfluences(n, Usd.TimeCode.EarliestTime()) if skin.HasJointInfluences() else None
        if got:
            ji, jw = (np.array(a) for a in got)
            k = skin.GetNumInfluencesPerComponent()
            order = skin.GetJointOrder()
            remap = np.array([index.get(str(j), -1) for j in order]) if order else np.arange(len(joints))
            ji = ji.reshape(n, k)
            valid = (ji >= 0) & (ji < len(remap))
            cols = np.where(valid, remap[np.clip(ji, 0, len(remap) - 1)], -1)
            rows = np.repeat(np.arange(n), k).reshape(n, k)
            ok = cols >= 0
            np.add.at(dense, (rows[ok], cols[ok]), jw.reshape(n, k)[ok])
        out.append(dense)
    return np.concatenate(out)


def _measure_feet(rig: _gait.CharacterRig, weights: np.ndarray, pts: np.ndarray):
    """(heel, ball, tip, ankle height) of the feet in the character frame, from the bind-pose points
    (``pts``) skinned mostly to each ankle and the joints below it; None when the feet have no points."""
    shapes = []
    for side in "lr":
        ankle = rig.roles[f"{side}_ankle"]
        below = [j for j in range(len(rig.joints)) if ankle in _ancestry(j, rig.parents)]
        sel = weights[:, below].sum(axis=1) >= 0.5
        if sel.sum() < 3:
            return None
        a = rig.pos(f"{side}_ankle")
        fwd = pts[sel, 1] - a[1]
        ball = rig.pos(f"{side}_toe")[1] - a[1] if f"{side}_toe" in rig.roles else fwd.max()
        shapes.append((fwd.min(), ball, fwd.max(), a[2] - pts[sel, 2].min()))
    heel, ball, tip, height = np.array(shapes).T
    if not (heel.max() < 0 < ball.min() <= tip.min() + 1e-9 and height.min() > 0):
        return None
    return float(heel.min()), float(ball.mean()), float(tip.max()), float(height.mean())


def _ancestry(j: int, parents) -> list[int]:
    out = [j]
    while parents[out[-1]] >= 0:
        out.append(int(parents[out[-1]]))
    return out


def _apply(m: np.ndarray, pts: np.ndarray) -> np.ndarray:
    return pts @ m[:3, :3].T + m[:3, 3]


def read_character(character: str | Path) -> Character:
    """Open and check a user's UsdSkel character (glTF/FBX conversions, Mixamo rigs, ...).

    The file's upAxis and metersPerUnit (lfusd.author.stage.world_frame) and every transform above
    and on the way to the skeleton are honoured; the character is turned to face +Y (its left hip
    towards -X) and its origin moved to the ground (its lowest bind-pose vertex) between its
    ankles. Refuses (one-line LfusdError, naming the file) a file without a skeleton, SkelRoot or
    bound mesh, a skeleton that is no biped (lfusd.author.skeletons.recognise_biped), blend shapes,
    a bind pose that is flat, lying down or upside down, and a stature outside 0.3-3 m."""
    cpath = Path(character)
    cstage, skel, root, skins = _open_character(cpath)
    wf = world_frame(cstage)
    W = wf.matrix()
    time = Usd.TimeCode.EarliestTime()  # transforms above the SkelRoot are baked in as they stand
    xcache = UsdGeom.XformCache(time)
    skel_world = _col(xcache.GetLocalToWorldTransform(skel.GetPrim()))
    try:
        rig = _gait.rig_from_skeleton(skel, W @ skel_world)
    except LfusdError as e:
        raise LfusdError(f"character {cpath}: {e}") from None
    mid = 0.5 * (rig.pos("l_ankle") + rig.pos("r_ankle"))
    leg = rig.pos("pelvis") - mid
    how = f"upAxis {wf.up_axis}, metersPerUnit {wf.meters_per_unit:g} and the transforms above its SkelRoot"
    if np.linalg.norm(leg) < 1e-3:
        raise LfusdError(
            f"character {cpath} has height 0: its pelvis and ankles coincide in the bind pose (with {how}); "
            "author the skeleton's bindTransforms as its standing pose"
        )
    tilt = np.degrees(np.arccos(np.clip(leg[2] / np.linalg.norm(leg), -1.0, 1.0)))
    if tilt > _UPRIGHT_DEG:
        raise LfusdError(
            f"character {cpath} is not standing: its legs lie {tilt:.0f} degrees off vertical (with {how}); "
            "author it upright along the file's upAxis or fix the rotation above its SkelRoot"
        )
    # Face +Y: the character's left (left hip minus right hip, or the ankles) turned to -X.
    left = (rig.pos("l_hip") - rig.pos("r_hip"))[:2]
    if np.linalg.norm(left) < 1e-6 * np.linalg.norm(leg):
        left = (rig.pos("l_ankle") - rig.pos("r_ankle"))[:2]
    R = np.eye(4)
    if np.linalg.norm(left) > 1e-9:
        yaw = np.pi / 2 - np.arctan2(-left[0], left[1])  # forward = left turned -90 degrees
        R[:2, :2] = [[np.cos(yaw), -np.sin(yaw)], [np.sin(yaw), np.cos(yaw)]]
    pts = _apply(R @ W @ skel_world, _bind_points(cpath, skins))
    if not np.all(np.isfinite(pts)):
        raise LfusdError(f"character {cpath}'s skinned meshes have non-finite points; fix or re-export them")
    T = np.eye(4)
    T[:3, 3] = -np.array([*(R[:3, :3] @ mid)[:2], pts[:, 2].min()])
    K = T @ R @ W
    height = float(pts[:, 2].max() - pts[:, 2].min())
    lo, hi = _CHARACTER_HEIGHT
    if not lo <= height <= hi:
        raise LfusdError(
            f"character {cpath} is {height:.3g} m tall (with {how}); give a character {lo:g}-{hi:g} m tall, "
            "or set the file's metersPerUnit to its real units (0.01 for centimetres)"
        )
    rig = _gait.rig_from_skeleton(skel, K @ skel_world)
    rig.foot_shape = _measure_feet(rig, _bind_weights(skel, skins), pts + T[:3, 3])
    if not rig.height > 0.5 * lo:
        raise LfusdError(
            f"character {cpath}'s head or pelvis joint is at the height of its feet (with {how}); "
            "author its bind pose standing, head up"
        )
    return Character(cpath, cstage, skel, root, K, rig, height)


def _load_character(stage: Usd.Stage, prim: Usd.Prim, character: Character):
    """Reference a read character at ``prim``; return (rig, skeleton path, K @ SkelRoot's world)."""
    asset = str(character.path.resolve())
    layer_path = stage.GetRootLayer().realPath
    if layer_path:  # relative, so the stage and its character can move together
        asset = os.path.relpath(asset, os.path.dirname(layer_path))
        asset = asset if asset.startswith(".") else "./" + asset
    top, needed = _character_prims(character)
    prim.GetReferences().AddReference(asset, top.GetPath())
    # Prims of the file that the character does not use (its cameras, lights, a ground) stay out.
    stage = prim.GetStage()
    walk = iter(Usd.PrimRange(top))
    for other in walk:
        path = other.GetPath()
        if any(path.HasPrefix(n) for n in needed):
            walk.PruneChildren()
        elif not any(n.HasPrefix(path) for n in needed):
            stage.OverridePrim(path.ReplacePrefix(top.GetPath(), prim.GetPath())).SetActive(False)
            walk.PruneChildren()
    # The person is one object, labelled person: class labels inside the file are blanked here.
    for inner in Usd.PrimRange(prim):
        if inner != prim and class_label(inner):
            UsdSemantics.LabelsAPI(inner, TAXONOMY).GetLabelsAttr().Set([])
    # The referenced prim's own transform is replaced by the person's motion: it and everything
    # above it in the file are folded into this matrix.
    top_world = _col(UsdGeom.XformCache(Usd.TimeCode.EarliestTime()).GetLocalToWorldTransform(top))
    rel = character.skel.GetPath().MakeRelativePath(top.GetPath())
    return character.rig, prim.GetPath().AppendPath(rel), character.K @ top_world


def _character_prims(character: Character) -> tuple[Usd.Prim, list[Sdf.Path]]:
    """(the prim of the character file to reference, the paths under it the character uses: its
    SkelRoot and the materials bound to its geometry). The referenced prim is the file's default
    prim or, when that does not hold the SkelRoot, the SkelRoot's top-level ancestor; a material
    outside it is refused in one line."""
    root = character.root
    default = character.stage.GetDefaultPrim()
    if default and root.GetPath().HasPrefix(default.GetPath()):
        top = default
    else:
        top = character.stage.GetPrimAtPath(root.GetPath().GetPrefixes()[0])
    needed = [root.GetPath()]
    for p in Usd.PrimRange(root):
        if not (p.IsA(UsdGeom.Gprim) or p.IsA(UsdGeom.Subset)):
            continue
        mat, _ = UsdShade.MaterialBindingAPI(p).ComputeBoundMaterial()
        if not mat:
            continue
        path = mat.GetPath()
        if not path.HasPrefix(top.GetPath()):
            raise LfusdError(
                f"character {character.path}'s material {path} lies outside {top.GetPath()}, the prim holding its SkelRoot; "
                f"move its materials under {top.GetPath()} (as glTF converters do)"
            )
        needed.append(path)
    return top, needed


def _person_rules(stage: Usd.Stage) -> dict:
    """The rules in force for a person added now, resolved as the rulebook resolves them for a
    moving object of class ``person`` (default rulebook < the stage's class rules; 'any' < class)."""
    from . import rules as constraints

    out: dict = {}
    for layer in (constraints.DEFAULT_RULES, constraints.stage_class_rules(stage)):
        for key in (ANY, "person"):
            out.update(layer.get(key, {}))
    return {k: v for k, v in out.items() if v not in ((), [], False, None)}


def _refuse_path_early(stage: Usd.Stage, geometry: StageGeometry, time: float, frames: np.ndarray, root_xy: np.ndarray,
                       ground_z: np.ndarray, stature: float, axes: np.ndarray) -> None:
    """Refuse, in one line naming the frame, what the rulebook would refuse once the person is
    made, where the root's path (``root_xy``, ``ground_z`` per frame, lfusd's world) alone makes
    it certain: the root outside the stage's ``lfusd:bounds`` (``in_bounds``: the body lies around
    its root), and a still object of a class the person must not intersect crossed by the body's
    axis between 55 % and 65 % of its stature (``no_interpenetration``: the torso encloses that
    segment, whatever the gait's sway and lean)."""
    from .labels import object_prim, object_table
    from .rules import _time_varying, _world_box
    from .vocabulary import BOUNDS, SURFACES

    rules = _person_rules(stage)
    default = stage.GetDefaultPrim()
    attr = default.GetAttribute(BOUNDS) if default else None
    if rules.get("in_bounds") and attr and attr.HasAuthoredValue():
        lo, hi = _world_box(geometry.frame, *np.array(attr.Get(), float))
        out = np.nonzero(np.any((root_xy < lo[:2]) | (root_xy > hi[:2]), axis=1))[0]
        if len(out):
            x, y = axes.T @ root_xy[out[0]]
            raise LfusdError(f"person path leaves the stage bounds (lfusd:bounds of {default.GetPath()}) at frame {frames[out[0]]} "
                             f"(at {x:.2f},{y:.2f}); keep the path inside them")
    classes = set(rules.get("no_interpenetration", ()))
    if not classes:
        return
    import open3d as o3d

    objects, _ = object_table(stage)
    still = [o for o in objects if o.label and o.label not in SURFACES and (ANY in classes or o.label in classes)
             and "[" not in o.prim_path and not _time_varying(object_prim(stage, o.prim_path))]
    # Only objects whose bounds reach the path's extent are meshed (a large set has thousands).
    bbox = UsdGeom.BBoxCache(Usd.TimeCode(time), [UsdGeom.Tokens.default_, UsdGeom.Tokens.render, UsdGeom.Tokens.proxy])
    plo, phi = root_xy.min(0), root_xy.max(0)

    def near(o) -> bool:
        box = bbox.ComputeWorldBound(object_prim(stage, o.prim_path)).ComputeAlignedRange()
        if box.IsEmpty():
            return True
        corners = geometry.frame.points(np.array([[a[0], b[1], c[2]] for a in (box.GetMin(), box.GetMax())
                                                  for b in (box.GetMin(), box.GetMax()) for c in (box.GetMin(), box.GetMax())]))
        return bool(np.all(corners.min(0)[:2] <= phi + 0.01) and np.all(corners.max(0)[:2] >= plo - 0.01))

    scene, info = o3d.t.geometry.RaycastingScene(), []
    for o in filter(near, still):
        for g in geometry.parts_of(o.prim_path):
            try:
                m = geometry.mesh(g, time)
            except LfusdError:  # geometry lfusd cannot mesh: left to the rulebook's check
                continue
            if len(m.triangles):
                scene.add_triangles(m.vertices.astype(np.float32), m.triangles.astype(np.uint32))
                info.append(o)
    if not info:
        return
    rays = np.zeros((len(frames), 6), np.float32)
    rays[:, :2], rays[:, 2], rays[:, 5] = root_xy, ground_z + 0.55 * stature, 1.0
    ans = scene.cast_rays(o3d.core.Tensor(rays))
    t, gid = ans["t_hit"].numpy(), ans["geometry_ids"].numpy()
    hit = np.nonzero(np.isfinite(t) & (t <= 0.1 * stature))[0]
    if len(hit):
        k = hit[0]
        o = info[int(gid[k])]
        x, y = axes.T @ root_xy[k]
        raise LfusdError(f"person path runs into {o.prim_path} (class {o.label}) at frame {frames[k]} (at {x:.2f},{y:.2f}): "
                         "the person would intersect it; route the path around it")


def _next_person_path(stage: Usd.Stage) -> Sdf.Path:
    i = 0
    while stage.GetPrimAtPath(f"{PEOPLE_SCOPE}/Person_{i:02d}"):
        i += 1
    return Sdf.Path(f"{PEOPLE_SCOPE}/Person_{i:02d}")


def add_person(stage: Usd.Stage, points, gait: str = "walk", speed: float = 1.3, start: int | None = None,
               character: str | Path | None = None, spec: _human.HumanSpec = _human.HumanSpec(),
               path: str | None = None, support=None, water=None, check: bool = True, progress=None) -> Usd.Prim:
    """Add a person walking/running along ``points`` (metres along the stage's horizontal axes,
    :func:`path_axes`) from frame ``start``; returns its prim.

    ``gait="idle"`` makes a person who stands (breathing, shifting weight) at the first point,
    facing the second.

    Refuses (LfusdError) a path with fewer than two points, a speed <= 0, a start frame outside
    the stage's range, a character without a skeleton, and a path on which the person would be
    over water or over no support at some frame (naming the first such frame). Support and water
    classes default to the rulebook's ``person`` rule. With ``check``, the finished person is
    checked with the rulebook (lfusd.author.rules) at every frame and removed again if it breaks
    a rule (what the path alone makes certain, the root out of the stage's bounds or the body's
    axis through a still object, is refused before the gait is computed); a run's flight phase is
    allowed by authoring the person's support ``tolerance``.
    A walk or run on a stage with no time range (one frame) is refused: it would not move.
    ``progress(what)`` is told each phase as it starts (a character's can take a minute).
    """

    def phase(what: str) -> None:
        log.info("add-person: %s", what)
        if progress is not None:
            progress(what)

    default_support, default_water = person_surfaces(stage)
    support = tuple(support) if support is not None else default_support
    water = tuple(water) if water is not None else default_water
    wf = world_frame(stage)
    axes = path_axes(wf)
    pts = check_points(points) @ axes.T  # lfusd's world (Z up, metres) from here on
    first, last = frame_range(stage)
    start = first if start is None else int(start)
    if not first <= start <= last:
        raise LfusdError(f"start frame {start} is outside the stage's range {first}-{last}; pick a frame in {first}-{last}")
    if gait not in ("walk", "run", "idle"):
        raise LfusdError(f"unknown gait {gait!r}; use walk, run or idle")
    if gait != "idle" and not speed > 0:
        raise LfusdError(f"speed {speed:g} m/s is not positive; give a {gait} speed > 0 m/s")
    if gait != "idle" and first == last:
        raise LfusdError(f"the stage has {'no time range' if not stage.HasAuthoredTimeCodeRange() else f'one frame ({first})'}, "
                         f"so the person would {gait} for one frame; give --frames N (the stage gets frames 1..N) or --gait idle")
    if character is not None:
        phase(f"reading the character {Path(character).name}")
        character = read_character(character)  # refuse a bad file before other work
    fps = stage.GetTimeCodesPerSecond() or _gait.FPS
    frames = np.arange(first, last + 1)

    route = SmoothPath(pts)
    phase(f"finding the ground under the path over {len(frames)} frames")
    geometry = StageGeometry(stage)
    surfaces = SupportSurfaces(stage, float(start), support, water, geometry)
    if gait == "walk" and speed > _gait._SPEED_LIMITS["walk"] or speed > _gait._SPEED_LIMITS["run"]:
        _gait.gait_params(gait, speed)  # raises the one-line error for too high a speed
    if gait == "idle":  # standing at the first point, facing along the path
        dist = np.zeros(len(frames))
    else:
        stature = character.rig.height if character is not None else spec.height
        dist, _, _ = _gait.journey(gait, speed, route.length, stature, frames, start, fps)
    # Refuse before authoring anything: the person's root must be over support at every frame.
    z, owners = surfaces.cast(route.at(dist)[0])
    for f, zz, own in zip(frames, z, owners):
        if own is None:
            x, y = axes.T @ route.at(dist[frames == f])[0][0]
            raise LfusdError(
                f"person path leaves the supporting surfaces at frame {f} (nothing labelled "
                f"{'/'.join(support[:4])}... under {x:.2f},{y:.2f}); keep the path on the ground"
            )
        if own[1] in surfaces.water:
            raise LfusdError(
                f"person path crosses water ({own[0]}, class {own[1]}) at frame {f}; route the path over a bridge or around it"
            )
    if check:  # the rulebook's refusals that the root's path alone makes certain, before the gait,
        # the skinning and the rulebook's check of the finished person (minutes on a large set)
        stature = character.rig.height if character is not None else spec.height
        _refuse_path_early(stage, geometry, float(start), frames, route.at(dist)[0], z, stature, axes)

    prim_path = Sdf.Path(path) if path else _next_person_path(stage)
    if not stage.GetPrimAtPath(PEOPLE_SCOPE) and str(prim_path).startswith(PEOPLE_SCOPE + "/"):
        UsdGeom.Scope.Define(stage, PEOPLE_SCOPE)
    if character is not None:
        prim = stage.DefinePrim(prim_path)
        rig, skel_path, post = _load_character(stage, prim, character)
        set_class_label(prim, "person")
        armless = [name for side, name in (("l", "left"), ("r", "right"))
                   if f"{side}_shoulder" not in rig.roles or f"{side}_elbow" not in rig.roles]
        if armless and gait != "idle":  # its arms cannot be brought down to its sides: say so, not silently
            log.warning("character %s: no %s arm recognised (a shoulder and elbow joint chain leaving the spine sideways), so it "
                        "keeps its rest pose while the person %ss (a T-posed arm stays held out)",
                        character.path.name, " or ".join(armless), gait)
    else:
        prim = _human.define_human(stage, prim_path, spec).GetPrim()
        rig, skel_path, post = _gait.human_rig(spec), prim_path.AppendChild(_human.SKELETON_NAME), None

    phase(f"moving the skeleton over {len(frames)} frames")
    params = _gait.gait_params(gait, speed, rig.height)
    table = None
    if gait != "idle":
        dist, table, _ = _gait.journey(gait, speed, route.length, rig.height, frames, start, fps)
    traj = _gait.Trajectory(frames, dist, route.at, surfaces.ground, table)
    motion = _gait.bake(rig, params, traj, fps)
    # The motion is in lfusd's world; the prim's parent space is the stage's (axes, units, transforms).
    parent = np.array(UsdGeom.XformCache(Usd.TimeCode(float(start))).GetLocalToWorldTransform(prim.GetParent()), np.float64).T
    pre = np.linalg.inv(wf.matrix() @ parent)
    _gait.write_motion(stage, skel_path, rig, motion, prim, post, pre)
    try:
        from .rules import DEFAULT_TOLERANCE, set_constraint
    except ImportError:
        DEFAULT_TOLERANCE, set_constraint = None, None
    if set_constraint is not None and gait == "run":
        gap = _flight_gap(stage, prim, frames, surfaces)
        if gap > DEFAULT_TOLERANCE:
            # Both feet leave the ground in a run: allow that height, rounded up to a centimetre.
            set_constraint(prim, "tolerance", float(np.ceil(gap * 100 + 1) / 100))
    if check:
        phase(f"checking the stage's rules at each of {len(frames)} frames")
        bad = _rulebook_violations(stage, prim, progress)
        if bad:
            stage.RemovePrim(prim.GetPath())
            raise LfusdError(f"the person would break the stage's rules ({bad[0]}); change the path or start frame")
    return prim



SPEEDS = {"walk": 1.3, "run": 3.5, "idle": 3.5}  # m/s when none is given (idle does not move)


def add_person_to_file(stage_path: str | Path, points, out: str | Path | None = None, *, gait: str = "walk",
                       speed: float | None = None, start: int | None = None, character: str | Path | None = None,
                       height: float = 1.75, build: float = 0.5, name: str | None = None,
                       force: bool = False, ground=(), frames: int | None = None, progress=None) -> tuple[Usd.Prim, str, float]:
    """`lfusd animate add-person`: add a person (:func:`add_person`) to the stage file ``stage_path``
    (into a new layer ``out`` over it when given) and save; returns the person's prim, the file
    written and the speed used (``speed`` None: :data:`SPEEDS`).

    ``height`` and ``build`` shape lfusd's procedural human (not a ``character``). ``name``: the
    person's absolute prim path, refused when a prim is there unless ``force`` (it is replaced).
    ``ground``: prim paths labelled ``ground`` first (:func:`label_ground`), for a stage without
    support labels; ``frames``: a stage without a time range gets frames 1..frames."""
    from .stage import usd_warnings

    with usd_warnings():  # what pxr posts (a character's broken references ...): one line each, not its raw output
        return _add_person_to_file(stage_path, points, out, gait=gait, speed=speed, start=start, character=character,
                                   height=height, build=build, name=name, force=force, ground=ground, frames=frames,
                                   progress=progress)


def _add_person_to_file(stage_path, points, out, *, gait, speed, start, character, height, build, name, force, ground,
                        frames, progress) -> tuple[Usd.Prim, str, float]:
    from .stage import open_for_edit, save_stage

    speed = SPEEDS.get(gait, SPEEDS["run"]) if speed is None else speed
    spec = _human.HumanSpec(height, build)
    spec.validate()
    stage = open_for_edit(stage_path, out)
    if name is not None:
        _clear_person_path(stage, name, force)
    label_ground(stage, ground)
    if frames is not None:
        set_frame_count(stage, frames)
    prim = add_person(stage, points, gait=gait, speed=speed, start=start, character=character, spec=spec, path=name,
                      progress=progress)
    target = str(out or stage_path)
    save_stage(stage, target)
    return prim, target, speed


def label_ground(stage: Usd.Stage, prims) -> None:
    """Label each of ``prims`` (absolute prim paths) ``ground``, so that a person walks on it: the
    command-line way (``--ground PRIM``) for a stage whose ground carries no class label. A prim
    missing, or labelled already with a class a person does not stand on, is refused in one line."""
    support, _ = person_surfaces(stage)
    for name in prims:
        path = Sdf.Path(name) if Sdf.Path.IsValidPathString(name) else None
        prim = stage.GetPrimAtPath(path) if path is not None and path.IsAbsolutePath() and path.IsPrimPath() else None
        if not prim:
            raise LfusdError(f"--ground {name!r} is not a prim of the stage; give the absolute path of the prim people walk on, e.g. /World/Floor")
        label = class_label(prim)
        if label and label not in support:
            raise LfusdError(f"--ground {name} is labelled {label!r}, which a person does not stand on ({', '.join(support[:6])}, ...); "
                             "give another prim")
        if not label:
            set_class_label(prim, "ground")


def set_frame_count(stage: Usd.Stage, frames: int) -> None:
    """Give a stage without a time range the frames 1..``frames`` (``--frames``); a stage with
    one is refused (its range stays the user's)."""
    if stage.HasAuthoredTimeCodeRange():
        first, last = frame_range(stage)
        raise LfusdError(f"the stage already has frames {first}-{last}; drop --frames (it is for a stage without a time range)")
    if frames < 2:
        raise LfusdError(f"--frames {frames}: a person moving needs at least 2 frames; give --frames 2 or more")
    stage.SetStartTimeCode(1)
    stage.SetEndTimeCode(int(frames))


def _clear_person_path(stage: Usd.Stage, name: str, force: bool) -> None:
    """Refuse a --name that is not an absolute prim path, or names a prim that exists (unless --force: removed)."""
    path = Sdf.Path(name) if Sdf.Path.IsValidPathString(name) else None
    if path is None or not path.IsAbsolutePath() or not path.IsPrimPath() or path == Sdf.Path.absoluteRootPath:
        raise LfusdError(f"--name {name!r} is not an absolute prim path; give one such as /World/People/Alice")
    if stage.GetPrimAtPath(path):
        if not force:
            raise LfusdError(f"stage already has a prim at {name}; choose another --name or pass --force to replace it")
        stage.RemovePrim(path)

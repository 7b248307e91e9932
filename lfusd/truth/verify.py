"""Independent verification of a dataset's motion ground truth against the stage's own geometry.

Every mesh of the stage is rebuilt with pxr (:class:`lfusd.author.geometry.StageGeometry`: UsdGeom
points and transforms, UsdSkel skinning) at t and t+-1. A ray through every pixel centre (K and
cam_to_world) is cast with Open3D's ``RaycastingScene``; the hit is recomputed in float64 on its
triangle, moved with that triangle to the other frame (same barycentric coordinates on the same
triangle), projected, and tested for visibility there with a second ray cast. That gives depth,
instance, flow, scene flow, disparity change and occlusion independently of Blender and of
:mod:`lfusd.truth.motion`; :func:`verify_dataset` compares a dataset with them.

Default thresholds (:data:`THRESHOLDS`), applied to the 99th percentile of the error on
*interior* pixels (foreground in both, at least ``EDGE_PX`` pixels from any instance edge or depth
edge of the traced image) for every object class and for all classes together:
flow 0.05 px, scene flow 1 mm (or 1e-3 of the object's size for objects under 1 m: the error is
scaled by max(1, 1 mm / (1e-3 x size)) before it is compared), depth 1e-4 relative, disparity change 0.05 px; instance ids must
agree on all but 0.1 % of interior pixels; occlusion masks must agree with ray-cast visibility on
99 % of the pixels that are foreground in both (over the whole view; per-class rates are only
reported, as a small object's disagreement at its edges is a large share of its pixels).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Iterable

import numpy as np

from ..camera import Camera, project, ray_directions
from ..errors import LfusdError
from ..layout import MANIFEST, MOTION_FILE
from ..keys import BACKGROUND_DEPTH, MOTION, accuracies, accuracy_units, names

# The accuracy of each verified key lives in lfusd.keys: relative depth, px, m, or for instance and
# occlusion the fraction of interior (foreground) pixels that disagree.
THRESHOLDS: dict[str, float] = accuracies()
UNITS = accuracy_units()
EDGE_PX = 2
DEPTH_EDGE_REL = 0.02  # neighbours whose depths differ by more than this are across a depth edge
SCENE_FLOW_REL = 1e-3  # scene flow is also held to this fraction of the object's size (small objects)
VISIBLE_EPS = 1e-4  # relative slack of the visibility ray cast (hits nearer than 1-eps occlude)


# -- tracing ---------------------------------------------------------------------------------


class TracedScene:
    """Open3D ray-casting scene of all stage meshes at one time, with float64 copies of them."""

    def __init__(self, geometry, time: float):
        import open3d as o3d

        self.time = time
        self.meshes = geometry.meshes(time)
        self.scene = o3d.t.geometry.RaycastingScene()
        self.geom_ids: list[int] = []
        for part, m in zip(geometry.parts, self.meshes):
            if len(m.triangles) == 0 or not geometry.visible(part, time):
                self.geom_ids.append(-1)
                continue
            gid = self.scene.add_triangles(
                o3d.core.Tensor(m.vertices.astype(np.float32)), o3d.core.Tensor(m.triangles.astype(np.uint32))
            )
            self.geom_ids.append(int(gid))
        self.by_gid = {g: i for i, g in enumerate(self.geom_ids) if g >= 0}

    def cast(self, origins: np.ndarray, dirs: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(t_hit float32 in units of |dir|, mesh index (-1 none), triangle id) per ray."""
        import open3d as o3d

        rays = np.concatenate([origins, dirs], axis=-1).reshape(-1, 6).astype(np.float32)
        ans = self.scene.cast_rays(o3d.core.Tensor(rays))
        t = ans["t_hit"].numpy()
        gid = ans["geometry_ids"].numpy().astype(np.int64)
        prim = ans["primitive_ids"].numpy().astype(np.int64)
        lut = np.full(max(self.geom_ids + [0]) + 2, -1, np.int64)
        for g, i in self.by_gid.items():
            lut[g] = i
        mesh = np.where(np.isfinite(t), lut[np.clip(gid, 0, len(lut) - 1)], -1)
        return t, mesh, prim


def _rays(K: np.ndarray, cam_to_world: np.ndarray, H: int, W: int) -> tuple[np.ndarray, np.ndarray]:
    v, u = np.mgrid[0:H, 0:W].astype(np.float64)
    d = ray_directions(u, v, Camera(K, cam_to_world))  # camera-z component 1
    return np.broadcast_to(np.asarray(cam_to_world, np.float64)[:3, 3], d.shape).copy(), d


def _hit_on_triangle(o, d, A, B, C):
    """Ray-plane hit parameter and barycentric (b1, b2) on triangles ABC, in float64."""
    e1, e2 = B - A, C - A
    n = np.cross(e1, e2)
    with np.errstate(divide="ignore", invalid="ignore"):
        t = ((A - o) * n).sum(-1) / (d * n).sum(-1)
        P = o + t[:, None] * d
        # Barycentric coordinates of P by the standard dot-product solve.
        w = P - A
        d00, d01, d11 = (e1 * e1).sum(-1), (e1 * e2).sum(-1), (e2 * e2).sum(-1)
        d20, d21 = (w * e1).sum(-1), (w * e2).sum(-1)
        den = d00 * d11 - d01 * d01
        b1 = (d11 * d20 - d01 * d21) / den
        b2 = (d00 * d21 - d01 * d20) / den
    return t, P, b1, b2


def _bounds(meshes) -> np.ndarray:
    """(n, 2, 3): each mesh's world-space min and max corner at the traced time (NaN when empty)."""
    out = np.full((len(meshes), 2, 3), np.nan)
    for i, m in enumerate(meshes):
        if len(m.vertices):
            out[i] = m.vertices.min(0), m.vertices.max(0)
    return out


def object_sizes(mesh_ids: np.ndarray, bounds: np.ndarray) -> np.ndarray:
    """Size (bounding-box diagonal, metres) of every instance id from its meshes' bounds;
    ``mesh_ids``: instance id per mesh (as :func:`object_ids_for` gives, last entry background)."""
    n = int(mesh_ids.max(initial=0)) + 1
    lo, hi = np.full((n, 3), np.inf), np.full((n, 3), -np.inf)
    ok = np.isfinite(bounds[:, 0, 0])
    np.minimum.at(lo, mesh_ids[:-1][ok], bounds[ok, 0])
    np.maximum.at(hi, mesh_ids[:-1][ok], bounds[ok, 1])
    with np.errstate(invalid="ignore"):
        size = np.linalg.norm(hi - lo, axis=1)
    return np.where(np.isfinite(size), size, np.inf)


def trace_motion(
    stage_or_geometry,
    frame: float,
    K: np.ndarray,
    cam_to_world_t: np.ndarray,
    cam_to_world_t1: np.ndarray,
    H: int,
    W: int,
    step: int = 1,
    baseline: float | None = None,
    scenes: dict | None = None,
) -> dict[str, Any]:
    """Independently traced ground truth of one view at ``frame`` towards ``frame + step``.

    ``stage_or_geometry``: a Usd.Stage or a StageGeometry; ``cam_to_world_t1`` is the view's
    pose at ``frame + step``. ``scenes`` (optional dict) caches TracedScene per time between calls.
    Returns depth (H,W; inf on background), position (H,W,3), mesh (H,W int; index into
    ``prim_paths``, -1 background), prim_paths, flow (H,W,2) to frame+step, scene_flow (H,W,3),
    disparity_change (H,W; needs ``baseline``), occluded (H,W bool: hidden or outside the image
    at frame+step) and valid (H,W bool: foreground whose mesh keeps its topology).
    """
    from ..author.geometry import StageGeometry

    geo = stage_or_geometry if isinstance(stage_or_geometry, StageGeometry) else StageGeometry(stage_or_geometry)
    scenes = {} if scenes is None else scenes
    for t in (frame, frame + step):
        if t not in scenes:
            scenes[t] = TracedScene(geo, t)
    s0, s1 = scenes[frame], scenes[frame + step]
    o, d = _rays(K, cam_to_world_t, H, W)
    o, d = o.reshape(-1, 3), d.reshape(-1, 3)
    _, mesh, tri = s0.cast(o, d)
    n = H * W
    depth = np.full(n, np.inf)
    pos = np.full((n, 3), np.nan)
    pos1 = np.full((n, 3), np.nan)
    valid = np.zeros(n, bool)
    for i, (m0, m1) in enumerate(zip(s0.meshes, s1.meshes)):
        sel = np.flatnonzero(mesh == i)
        if sel.size == 0:
            continue
        tr = m0.triangles[tri[sel]]
        t, P, b1, b2 = _hit_on_triangle(o[sel], d[sel], *(m0.vertices[tr[:, k]] for k in range(3)))
        depth[sel] = t  # direction has camera-z 1, so the ray parameter is planar depth
        pos[sel] = P
        if m1.vertices.shape == m0.vertices.shape and np.array_equal(m1.triangles, m0.triangles):
            V = m1.vertices[tr]
            pos1[sel] = (1 - b1 - b2)[:, None] * V[:, 0] + b1[:, None] * V[:, 1] + b2[:, None] * V[:, 2]
            valid[sel] = True
    u1, v1, z1 = project(pos1, Camera(K, cam_to_world_t1))
    v, u = np.mgrid[0:H, 0:W].astype(np.float64)
    flow = np.stack([u1 - u.ravel(), v1 - v.ravel()], -1)
    inside = (u1 >= -0.5) & (u1 <= W - 0.5) & (v1 >= -0.5) & (v1 <= H - 0.5) & (z1 > 0)
    # Visibility at frame+step: the first hit from the camera towards the moved point is the point.
    C1 = np.asarray(cam_to_world_t1, np.float64)[:3, 3]
    vis = np.zeros(n, bool)
    idx = np.flatnonzero(valid & inside)
    if idx.size:
        t_hit, _, _ = s1.cast(np.broadcast_to(C1, (idx.size, 3)), pos1[idx] - C1)
        vis[idx] = t_hit >= 1 - VISIBLE_EPS
    fb = float(K[0, 0]) * float(baseline) if baseline else np.nan
    with np.errstate(divide="ignore", invalid="ignore"):
        dchange = fb / z1 - fb / depth
    return {
        "depth": depth.reshape(H, W),
        "position": pos.reshape(H, W, 3),
        "mesh": mesh.reshape(H, W),
        "prim_paths": [m.prim_path for m in s0.meshes],
        "mesh_bounds": _bounds(s0.meshes),
        "flow": flow.reshape(H, W, 2),
        "scene_flow": (pos1 - pos).reshape(H, W, 3),
        "disparity_change": dchange.reshape(H, W),
        "occluded": (valid & ~vis).reshape(H, W),
        "valid": valid.reshape(H, W),
    }


# -- comparison ------------------------------------------------------------------------------


def _dilate(mask: np.ndarray, r: int) -> np.ndarray:
    out = mask.copy()
    for _ in range(r):
        m = out.copy()
        m[1:] |= out[:-1]
        m[:-1] |= out[1:]
        m[:, 1:] |= out[:, :-1]
        m[:, :-1] |= out[:, 1:]
        out = m
    return out


def interior_mask(instance: np.ndarray, depth: np.ndarray, edge_px: int = EDGE_PX) -> np.ndarray:
    """Foreground pixels more than ``edge_px`` pixels away from the pixels touching an instance or depth edge."""
    fg = np.isfinite(depth) & (instance > 0)
    edge = np.zeros_like(fg)
    for axis in (0, 1):
        a = [slice(None)] * 2
        b = [slice(None)] * 2
        a[axis], b[axis] = slice(1, None), slice(None, -1)
        da, db = depth[tuple(a)], depth[tuple(b)]
        with np.errstate(invalid="ignore"):
            jump = (instance[tuple(a)] != instance[tuple(b)]) | ~(np.abs(da - db) <= DEPTH_EDGE_REL * np.minimum(da, db))
        edge[tuple(a)] |= jump
        edge[tuple(b)] |= jump
    return fg & ~_dilate(edge, edge_px)


def object_ids_for(prim_paths: list[str], objects: dict) -> np.ndarray:
    """Instance id of each gprim (or point-instance part) path: the object whose path is the path or
    its nearest ancestor (``/A[i]/B`` is below ``/A[i]``), 0 when none. Linear: one dict lookup per
    ancestor of each path."""
    out = np.zeros(len(prim_paths) + 1, np.int64)  # last entry: background (-1 index)
    owner = {o.prim_path: int(i) for i, o in objects.items()}
    for k, p in enumerate(prim_paths):
        while p:
            if p in owner:
                out[k] = owner[p]
                break
            p = p[: max(p.rfind("/"), p.rfind("["))]  # drop the last name or instance index
    return out


@dataclass
class Row:
    """Error statistics of one key and class in one view and frame."""

    frame: int
    view: tuple[int, int]
    key: str
    label: str
    count: int
    median: float
    p99: float
    max: float
    threshold: float

    @property
    def ok(self) -> bool:
        return self.count == 0 or self.p99 <= self.threshold


@dataclass
class VerifyReport:
    """All rows of a verification; ``ok`` when no row exceeds its threshold."""

    rows: list[Row] = field(default_factory=list)
    problems: list[str] = field(default_factory=list)  # views with no data to compare (missing or damaged files)

    def compared(self) -> dict[str, int]:
        """Pixels compared per key (all classes together), over every frame and view."""
        out: dict[str, int] = {}
        for r in self.rows:
            if r.label == ALL:
                out[r.key] = out.get(r.key, 0) + r.count
        return out

    @property
    def ok(self) -> bool:
        """No row exceeds its threshold, and every key checked compared at least one pixel:
        a check that compared nothing has failed."""
        return bool(self.rows) and not self.problems and all(r.ok for r in self.rows) and all(self.compared().values())

    def failures(self) -> list[str]:
        """One line per failing row, naming the key, class, frame and view; one per key that
        compared nothing; one when nothing at all was compared."""
        if not self.rows:
            return self.problems + ["nothing to compare: the frames and views selected hold no ground truth to check; select some with --frames/--views"]
        out = list(self.problems)
        out += [f"{key}: nothing to compare (0 px over every frame and view); check that --stage is the rendered stage"
               for key, n in self.compared().items() if n == 0]
        for r in self.rows:
            if r.ok:
                continue
            where = f"{r.key} of view {r.view[0]},{r.view[1]} at frame {r.frame} ({r.label or 'unlabelled'}): "
            if UNITS.get(r.key) == "frac":
                out.append(where + f"disagrees on {100 * r.p99:.3g} % of {r.count} px > {100 * r.threshold:g} %")
            else:
                out.append(where + f"p99 error {r.p99:.3g} {UNITS[r.key]} > {r.threshold:g} over {r.count} px")
        return out

    def summary(self) -> list[dict]:
        """Per key and class over all frames and views: pixel count, median of medians, worst p99 and max."""
        out: dict[tuple[str, str], dict] = {}
        for r in self.rows:
            e = out.setdefault((r.key, r.label), {"key": r.key, "label": r.label, "count": 0, "medians": [], "p99": 0.0, "max": 0.0, "threshold": r.threshold, "ok": True})
            e["count"] += r.count
            if r.count:
                e["medians"].append(r.median)
                e["p99"] = max(e["p99"], r.p99)
                e["max"] = max(e["max"], r.max)
            e["ok"] &= r.ok
        for e in out.values():
            e["median"] = float(np.median(e.pop("medians"))) if e["count"] else 0.0
        return list(out.values())

    def table(self) -> str:
        """Plain-text table of :meth:`summary`."""
        lines = [f"{'key':<17}{'class':<14}{'pixels':>9}{'median':>11}{'p99':>11}{'max':>11}{'limit':>9}  ok"]
        for e in self.summary():
            lines.append(
                f"{e['key']:<17}{(e['label'] or 'unlabelled'):<14}{e['count']:>9}"
                f"{e['median']:>11.3g}{e['p99']:>11.3g}{e['max']:>11.3g}{e['threshold']:>9.3g}  {'yes' if e['ok'] else 'NO'}"
            )
        return "\n".join(lines)


ALL = "(all)"


def _stats_rows(frame, view, key, err, classes, labels_of, threshold, rate=False) -> list[Row]:
    """Rows for all classes and each class; ``rate``: err is 0/1 and every statistic is its mean."""
    rows = []
    for label in [ALL] + sorted(set(labels_of[classes].tolist())):
        sel = np.ones(err.shape, bool) if label == ALL else labels_of[classes] == label
        e = err[sel]
        if e.size == 0:
            rows.append(Row(frame, view, key, label, 0, 0.0, 0.0, 0.0, threshold))
            continue
        if rate:
            # Occlusion disagreement lives on the edges of what is seen at t+-1: its limit is on
            # the whole image, the per-class rates are reported for information only.
            limit = np.inf if key.startswith("occlusion") and label != ALL else threshold
            m = float(e.mean())
            rows.append(Row(frame, view, key, label, int(e.size), m, m, m, limit))
        else:
            rows.append(Row(frame, view, key, label, int(e.size), float(np.median(e)), float(np.percentile(e, 99)), float(e.max()), threshold))
    return rows


def compare_view(
    data: dict[str, np.ndarray | None],
    fwd: dict | None,
    bwd: dict | None,
    objects: dict,
    frame: int,
    view: tuple[int, int],
    thresholds: dict[str, float] | None = None,
    still: dict | None = None,
) -> list[Row]:
    """Error rows of one view: ``data`` holds the dataset's arrays (missing keys None), ``fwd``/``bwd``
    traces towards t+1 / t-1, or ``still`` (a trace at t alone) for a frame with neither neighbour:
    then only the static keys (depth, instance) are compared."""
    thr = {**THRESHOLDS, **(thresholds or {})}
    tr = fwd or bwd or still
    if tr is None:
        raise ValueError("compare_view needs a trace: fwd, bwd or still")
    ids = object_ids_for(tr["prim_paths"], objects)
    inst_tr = ids[tr["mesh"]]  # mesh -1 -> last entry 0
    labels_of = np.array([""] + [str(objects[i].label) for i in sorted(objects)], dtype=object)
    id_to_row = np.zeros(max([0] + list(objects)) + 1, np.int64)
    for k, i in enumerate(sorted(objects)):
        id_to_row[i] = k + 1
    inst_ds = np.asarray(data["instance"]) if data.get("instance") is not None else inst_tr
    depth_ds = np.asarray(data["depth"], np.float64)
    interior = interior_mask(inst_tr, tr["depth"]) & np.isfinite(depth_ds) & (depth_ds < BACKGROUND_DEPTH)
    cls = id_to_row[np.clip(inst_tr, 0, len(id_to_row) - 1)]
    rows: list[Row] = []

    def add(key, err, sel, rate=False):
        rows.extend(_stats_rows(frame, view, key, err[sel], cls[sel], labels_of, thr[key], rate))

    with np.errstate(invalid="ignore", divide="ignore"):
        add("depth", np.abs(depth_ds - tr["depth"]) / tr["depth"], interior)
        if data.get("instance") is not None:
            add("instance", (inst_ds != inst_tr).astype(float), interior, rate=True)
        for name, trace, step in (("fwd", fwd, "valid_fwd"), ("bwd", bwd, "valid_bwd")):
            if trace is None:
                continue
            ok = interior & trace["valid"]
            if data.get(step) is not None:
                ok &= np.asarray(data[step], bool)
            if data.get(f"flow_{name}") is not None:
                add(f"flow_{name}", np.linalg.norm(np.asarray(data[f"flow_{name}"], np.float64) - trace["flow"], axis=-1), ok)
            if name == "fwd" and data.get("scene_flow") is not None:
                # Held to the limit or SCENE_FLOW_REL of the object's size, whichever is smaller:
                # 1 mm says nothing about a 2 cm chess piece. The error is scaled to the limit.
                size = object_sizes(ids, trace["mesh_bounds"])[np.clip(inst_tr, 0, None)]
                scale = np.maximum(1.0, thr["scene_flow"] / (SCENE_FLOW_REL * size))
                add("scene_flow", scale * np.linalg.norm(np.asarray(data["scene_flow"], np.float64) - trace["scene_flow"], axis=-1), ok)
            if name == "fwd" and data.get("disparity_change") is not None and np.isfinite(trace["disparity_change"][ok]).all():
                add("disparity_change", np.abs(np.asarray(data["disparity_change"], np.float64) - trace["disparity_change"]), ok)
            occ = data.get(f"occlusion_{name}")
            if occ is not None:
                both = (inst_tr > 0) & np.isfinite(depth_ds) & (depth_ds < BACKGROUND_DEPTH) & trace["valid"]
                add(f"occlusion_{name}", (np.asarray(occ, bool) != trace["occluded"]).astype(float), both, rate=True)
    return rows


# -- datasets --------------------------------------------------------------------------------

KEYS = ("depth", "instance", *names(MOTION))  # the dataset's keys that verification reads


def _read_optional(ds, frame, view, key):
    try:
        return ds.read(frame, view, key)
    except (KeyError, FileNotFoundError, LfusdError):
        return None


def dataset_stage_path(ds) -> str | None:
    """The stage a dataset was rendered from: ``ds.stage_path``, else its manifest's stage path."""
    path = getattr(ds, "stage_path", None)
    if path:
        return str(path)
    manifest = getattr(ds, "manifest", None) or {}
    return (manifest.get("stage") or {}).get("path")


def verify_dataset(
    ds,
    stage_path: str | None = None,
    frames: Iterable[int] | None = None,
    views: Iterable[tuple[int, int]] | None = None,
    thresholds: dict[str, float] | None = None,
    baseline: float | None = None,
    progress=None,
) -> VerifyReport:
    """Verify a dataset reader against its stage (see the module docstring).

    ``ds`` needs ``frames``, ``views``, ``intrinsics(view)``, ``cam_to_world(frame, view)``,
    ``read(frame, view, key)`` and ``objects`` ({id: obj with .prim_path, .label}); the stage
    comes from ``stage_path``, ``ds.stage_path`` or ``ds.manifest['stage']['path']``; ``baseline`` (or ``ds.baseline``) enables
    the disparity-change check. ``progress(frame, view)`` is called before each view.
    """
    from ..author.geometry import StageGeometry
    from ..author.stage import open_stage

    stage_path = stage_path or dataset_stage_path(ds)
    if not stage_path:
        raise LfusdError("verify needs the stage the dataset was rendered from; pass --stage PATH")
    geo = StageGeometry(open_stage(stage_path))
    baseline = baseline if baseline is not None else getattr(ds, "baseline", None)
    # Every frame the manifest lists, complete or not: a view missing there is a failure, not a skip.
    manifest = getattr(ds, "manifest", None) or {}
    all_frames = sorted(int(f) for f in manifest.get("frames") or ds.frames)
    expect_motion = bool(manifest.get("settings", {}).get("motion"))
    frames = all_frames if frames is None else [int(f) for f in frames]
    views = list(ds.views) if views is None else [tuple(v) for v in views]
    for f in frames:
        if f not in all_frames:
            raise LfusdError(f"frame {f} is not in the dataset (frames {all_frames[0]}-{all_frames[-1]}); pick one of its frames")
    for v in views:
        if tuple(v) not in [tuple(x) for x in ds.views]:
            raise LfusdError(f"view {v[0]},{v[1]} is not in the dataset; pick one of its views")
    objects = ds.objects
    report = VerifyReport()
    scenes: dict = {}
    for f in frames:
        for view in views:
            if progress:
                progress(f, view)
            where = f"frame {f} view {view[0]},{view[1]}"
            try:
                ds.read(f, view, "depth")
            except (FileNotFoundError, LfusdError) as e:
                report.problems.append(f"{where}: no depth to compare ({str(e).split(';')[0]}); rerun the render command to repair it")
                continue
            data = {k: _read_optional(ds, f, view, k) for k in KEYS}
            lacking = [k for k in names(MOTION) if data[k] is None]
            if expect_motion and lacking:
                report.problems.append(f"{where}: no {', '.join(lacking)} to compare ({MOTION_FILE} missing or damaged); "
                                       "rerun render-video or 'lfusd flow' to repair it")
            H, W = np.asarray(data["depth"]).shape[:2]
            K = np.asarray(ds.intrinsics(view), np.float64)
            c2w = np.asarray(ds.cam_to_world(f, view), np.float64)
            fwd = bwd = None
            if f + 1 in all_frames:
                fwd = trace_motion(geo, f, K, c2w, ds.cam_to_world(f + 1, view), H, W, 1, baseline, scenes)
            if f - 1 in all_frames:
                bwd = trace_motion(geo, f, K, c2w, ds.cam_to_world(f - 1, view), H, W, -1, baseline, scenes)
            # A frame without rendered neighbours has no motion keys to check: its static keys are.
            still = trace_motion(geo, f, K, c2w, c2w, H, W, 0, baseline, scenes) if fwd is None and bwd is None else None
            report.rows.extend(compare_view(data, fwd, bwd, objects, f, tuple(view), thresholds, still=still))
            for t in [t for t in scenes if t < f - 1]:
                del scenes[t]  # frames are visited in order: free meshes no longer needed
    return report


def verify(
    out,
    *,
    stage: str | None = None,
    rig: str | None = None,
    frames: Iterable[int] | None = None,
    views: Iterable[tuple[int, int]] | None = None,
    thresholds: dict[str, float] | None = None,
    progress=None,
) -> dict[str | None, VerifyReport]:
    """Verify the dataset in folder ``out`` against its stage: {rig name: report} for ``rig`` or every rig.

    ``frames``/``views`` default to all rendered ones; ``thresholds`` overrides keys of
    :data:`THRESHOLDS`; ``stage`` replaces the stage the manifest records; ``progress(frame, view)``
    is called before each view. What `lfusd verify` and `lfusd render-video --verify` run.
    """
    from ..data import export

    unknown = sorted(set(thresholds or {}) - set(THRESHOLDS))
    if unknown:
        raise LfusdError(f"unknown threshold {unknown[0]!r}; use one of {', '.join(THRESHOLDS)}")
    from ..data.integrity import check_dataset

    reports = {}
    for ds in export.open_datasets(out, rig):
        if not ds.frames:
            raise LfusdError(f"dataset {out} has no completely rendered frame; finish the render first")
        # First every view's files against its record (what --integrity checks): a damaged file
        # verify does not read (a truncated rgb.exr) fails the dataset too.
        root = getattr(ds, "root", None)
        damaged = [] if root is None or not (Path(root) / MANIFEST).is_file() else \
            check_dataset(root, ds.rig_name, frames=frames, views=views)[1]  # a reader of files, not one made in memory
        report = verify_dataset(ds, stage_path=stage, frames=frames, views=views, thresholds=thresholds, progress=progress)
        report.problems[:0] = [f"{p}; rerun the render command to repair it" for p in damaged]
        reports[getattr(ds, "rig_name", None)] = report
    return reports

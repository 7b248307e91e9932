"""Independent verification of a dataset's motion ground truth against the stage's own geometry.

Every mesh of the stage is rebuilt with pxr (:class:`lfusd.author.geometry.StageGeometry`: UsdGeom
points and transforms, UsdSkel skinning) at t and t+-1. The first hit of the ray through every
pixel centre (K and cam_to_world) is found per triangle by an exact float64 ray-triangle test
(:meth:`TracedScene.grid_hits`, lfusd.truth._grid_numba: the answer of Open3D's ``RaycastingScene``
cast wherever a ray is not within rounding of two surfaces, at a tenth of its cost; rays off the
grid, through a lens and the tie candidates are cast with Open3D); the hit is recomputed in float64
on its triangle, moved with that triangle to the other frame (same barycentric coordinates on the
same triangle), projected, and tested for visibility there with an Open3D ray cast. That gives depth,
instance, flow, scene flow, disparity change and occlusion independently of Blender and of
:mod:`lfusd.truth.motion`; :func:`verify_dataset` compares a dataset with them.

Every pixel is compared where the dataset or the trace sees a surface, silhouettes included; the
motion keys where both call the pixel valid. Limits (:data:`THRESHOLDS`, from lfusd.keys): flow
0.05 px, scene flow 1 mm (or 1e-3 of the object's size, never below the 2^-17 m storage step:
the error is scaled to the limit), depth 1e-4 relative, disparity change 0.05 px; instance and
occlusion are agree / disagree. A key fails when any compared pixel exceeds its limit and no tie
explains it (instance, occlusion: when any pixel disagrees, or more than a limit the user sets);
the report fails when more than ``UNCHECKED_FRACTION`` (0.1 %) of the pixels the dataset calls
valid cannot be checked (their mesh changes topology in the stage). Ties (:data:`TIE_KINDS`): a
pixel over a limit is accepted when a second surface its sample may have hit within float
tolerance agrees on every key: a ray moved by the float bound of an edge near the sample
(:func:`_edge_step`: at least ``TIE_PX``, 1e-3 px; more where coordinates are large against the
depth), the second hit within ``VISIBLE_EPS`` of such a ray moved by ``EDGE_FRACTIONS`` of that
bound (a back face sharing a silhouette edge), or a second hit along its own ray within
``VISIBLE_EPS`` (1e-4) of the distance; for
occlusion, also a surface within [eps/10, 10 eps] in front of the point at t+-1; for depth, an
error within the float32 bound of a grazing hit (:func:`_clear_grazing_ties`).
Ties are counted and reported. :meth:`VerifyReport.certificate` is what a dataset records.

Every other key and record is checked exactly (:data:`EXACT`): ``normal`` against the traced
triangle (unit length, the side the camera sees), ``valid_fwd``/``valid_bwd`` (set exactly where the
trace knows the motion, nowhere past the rendered range), ``semantic``, ``mixed`` (decided again on
verify's own corner rays and the stage's own triangles' discontinuity edges: lfusd.truth.footprint), the object table and the manifest's rig against the stage (the trace
takes the stage's rig). Per object and view, the mean signed error of flow, scene flow and
disparity change is held to a tenth of the limit (the ``<key>_bias`` rows).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Iterable

import numpy as np

from ..camera import Camera, project, ray_directions
from ..errors import LfusdError
from ..layout import MANIFEST, MOTION_FILE
from ..keys import BACKGROUND_DEPTH, KEYS as KEY_TABLE, MOTION, accuracies, accuracy_units, names

# The accuracy of each verified key lives in lfusd.keys: relative depth, px, m, or for instance and
# occlusion the fraction of interior (foreground) pixels that disagree.
THRESHOLDS: dict[str, float] = accuracies()
# Keys and records checked exactly (no user override): the normal's side (1 - cos of its angle to the
# traced triangle's normal facing the camera: over 1, it faces away), validity and semantic class
# (any disagreement fails).
EXACT: dict[str, float] = {"normal": 1.0, "semantic": 0.0, "valid_fwd": 0.0, "valid_bwd": 0.0, "mixed": 0.0}
UNITS = {**accuracy_units(), "normal": "1-cos", "semantic": "frac", "valid_fwd": "frac", "valid_bwd": "frac", "mixed": "frac"}
# mixed is decided again from verify's own corner rays (lfusd.truth.visibility's rule); a pixel whose
# corners differ in depth or flow by MIXED_BAND times the rule's limits (either way) may be either.
MIXED_BAND = (0.8, 1.25)
NORMAL_LENGTH_TOL = 1e-3  # |normal| - 1: the float16 storage adds at most 2.4e-4 per component
# Bias: per object and view, the mean signed error of these keys is held to BIAS_FRACTION of the key's
# per-pixel limit (0.005 px, 0.1 mm), never below the storage step of scene flow (2^-17 m), over
# objects with at least BIAS_MIN_PX compared pixels (fewer: the per-pixel limit alone).
BIAS_KEYS = ("flow_fwd", "flow_bwd", "scene_flow", "disparity_change")
BIAS_FRACTION = 0.1
BIAS_MIN_PX = 100
BIAS = "_bias"  # suffix of the bias rows' keys
SCENE_FLOW_REL = 1e-3  # scene flow is also held to this fraction of the object's size (small objects)
SCENE_FLOW_FLOOR = 2.0**-17  # ... but never below its storage step (lfusd.keys: multiples of 2^-17 m)
from .visibility import VISIBLE_EPS  # the tie rule of visibility, shared with the derivation


# -- tracing ---------------------------------------------------------------------------------


class TracedScene:
    """Open3D ray-casting scene of all stage meshes at one time, with float64 copies of them: per mesh
    (:attr:`meshes`) and concatenated (:attr:`V`, :attr:`T`: every mesh's triangles, indices into V;
    mesh i's triangles start at ``tri_offset[i]``), so that hits on any mesh are resolved in one pass."""

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
        self.lut = np.full(max(self.geom_ids + [0]) + 2, -1, np.int64)
        for g, i in self.by_gid.items():
            self.lut[g] = i
        nv = np.array([len(m.vertices) for m in self.meshes], np.int64)
        nt = np.array([len(m.triangles) for m in self.meshes], np.int64)
        self.vert_offset = np.concatenate([[0], np.cumsum(nv)])
        self.tri_offset = np.concatenate([[0], np.cumsum(nt)])
        self.tri_mesh = np.repeat(np.arange(len(self.meshes)), nt)  # per row of T (below): its mesh
        self.traced_rows = np.array([g >= 0 for g in self.geom_ids], bool)[self.tri_mesh]  # per row of T: in the Open3D scene
        self.V = np.concatenate([np.asarray(m.vertices, np.float64).reshape(-1, 3) for m in self.meshes] + [np.zeros((0, 3))])
        self.T = np.concatenate([np.asarray(m.triangles, np.int64).reshape(-1, 3) + o for m, o in zip(self.meshes, self.vert_offset)]
                                + [np.zeros((0, 3), np.int64)])
        self.prim_paths = [m.prim_path for m in self.meshes]
        self.bounds = _bounds(self.meshes)
        self._same: dict = {}  # per other time: same topology per mesh; ("static", t), ("moving", t): see below
        self._surface: tuple | None = None  # the last full-grid surface (key, value): shared by a view's traces
        self._edges: tuple | None = None
        self._near: tuple | None = None  # (moving scene, camera, what moved's nearest depth per pixel): see visibility_of

    def static_triangles(self, other: "TracedScene") -> np.ndarray:
        """Per triangle (rows of T): whether ``other`` (another time) holds it traced, with the same
        topology and its three vertices the same bit for bit (it stands still from one time to the other)."""
        key = ("static", other.time)
        if key not in self._same:
            same = self.same_topology(other)
            out = np.zeros(len(self.T), bool)
            for m in np.flatnonzero(same[:-1]):
                if self.geom_ids[m] < 0 or other.geom_ids[m] < 0:
                    continue
                a0, b0, a1 = self.vert_offset[m], self.vert_offset[m + 1], other.vert_offset[m]
                still = (self.V[a0:b0] == other.V[a1:a1 + b0 - a0]).all(axis=1)
                out[self.tri_offset[m]:self.tri_offset[m + 1]] = still[self.T[self.tri_offset[m]:self.tri_offset[m + 1]] - a0].all(axis=1)
            self._same[key] = out
        return self._same[key]

    def moving_scene(self, other: "TracedScene"):
        """(Open3D scene, V, their rows of T) of this time's traced triangles that do not stand still
        since ``other`` (:meth:`static_triangles`), or None when there are none (built once per pair)."""
        import open3d as o3d

        key = ("moving", other.time)
        if key not in self._same:
            moving = self.traced_rows & ~self.static_triangles(other)
            scene = None
            if moving.any():
                scene = o3d.t.geometry.RaycastingScene()
                scene.add_triangles(o3d.core.Tensor(self.V.astype(np.float32)), o3d.core.Tensor(self.T[moving].astype(np.uint32)))
                scene = (scene, self.V, np.ascontiguousarray(self.T[moving]))
            self._same[key] = scene
        return self._same[key]

    def edges(self) -> tuple[np.ndarray, np.ndarray, dict]:
        """The traced meshes' triangles (rows of T), the mesh index of each, and their edge table
        (lfusd.truth.footprint.edge_table): the ``mixed`` footprint's discontinuity edges."""
        if self._edges is None:
            from .footprint import edge_table

            keep = self.traced_rows
            T, mesh = np.ascontiguousarray(self.T[keep]), self.tri_mesh[keep]
            self._edges = (T, mesh, edge_table(self.V, T))
        return self._edges

    def same_topology(self, other: "TracedScene") -> np.ndarray:
        """Per mesh: whether ``other`` (another time of the same stage) holds it with the same
        vertices count and triangles (then a point keeps its barycentric coordinates)."""
        if other.time not in self._same:
            self._same[other.time] = np.array([m1.vertices.shape == m0.vertices.shape and np.array_equal(m1.triangles, m0.triangles)
                                               for m0, m1 in zip(self.meshes, other.meshes)] + [False], bool)
        return self._same[other.time]

    def _rays(self, origins: np.ndarray, dirs: np.ndarray):
        import open3d as o3d

        rays = np.empty((len(dirs), 6), np.float32)
        rays[:, :3] = origins
        rays[:, 3:] = dirs
        return o3d.core.Tensor(rays)

    def _mesh_of(self, gid: np.ndarray) -> np.ndarray:
        return self.lut[np.clip(gid, 0, len(self.lut) - 1)]

    def all_hits(self, origins: np.ndarray, dirs: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """Every surface along each ray: (ray index, t_hit, mesh index, triangle id) per hit."""
        ans = self.scene.list_intersections(self._rays(origins, dirs))
        splits = ans["ray_splits"].numpy().astype(np.int64)
        ray = np.repeat(np.arange(len(splits) - 1), np.diff(splits))
        gid = ans["geometry_ids"].numpy().astype(np.int64)
        return ray, ans["t_hit"].numpy(), self._mesh_of(gid), ans["primitive_ids"].numpy().astype(np.int64)

    def cast(self, origins: np.ndarray, dirs: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(t_hit float32 in units of |dir|, mesh index (-1 none), triangle id) per ray."""
        return self.cast_rays(self._rays(origins, dirs))

    def grid_hits(self, A: np.ndarray, origin: np.ndarray, u0: float, v0: float, W: int, H: int) -> tuple[np.ndarray, np.ndarray]:
        """(mesh index (-1 none), triangle id) of the first hit of each ray of a pinhole's H x W grid of
        samples (u0 + i, v0 + j), raster order: the rays from ``origin`` along A (u, v, 1). What
        :meth:`cast_rays` answers for them (lfusd.truth._grid_numba: float64, watertight; the two
        differ only where a ray meets two surfaces within rounding, which verify's tie rule decides)."""
        from ._grid_numba import grid_first_hits

        A = np.ascontiguousarray(A, np.float64)
        n = H * W
        depth, row, mesh, tri = np.empty(n), np.empty(n, np.int64), np.empty(n, np.int64), np.empty(n, np.int64)
        grid_first_hits(self.V, self.T, self.traced_rows, np.ascontiguousarray(origin, np.float64), A, np.ascontiguousarray(np.linalg.inv(A)),
                        float(u0), float(v0), int(W), int(H), depth, row, self.tri_mesh, self.tri_offset, mesh, tri)
        return mesh, tri

    def cast_rays(self, rays) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """:meth:`cast` of rays as Open3D takes them ((N, 6) float32: origin, direction)."""
        import open3d as o3d

        from . import _verify_numba as _numba

        ans = self.scene.cast_rays(rays if isinstance(rays, o3d.core.Tensor) else _tensor(rays))
        t = ans["t_hit"].numpy()
        mesh, prim = np.empty(len(t), np.int64), np.empty(len(t), np.int64)
        _numba.resolve_hits(t, ans["geometry_ids"].numpy(), ans["primitive_ids"].numpy(), self.lut, mesh, prim)
        return t, mesh, prim


def _rays(K: np.ndarray, cam_to_world: np.ndarray, H: int, W: int) -> tuple[np.ndarray, np.ndarray]:
    v, u = np.mgrid[0:H, 0:W].astype(np.float64)
    d = ray_directions(u, v, Camera(K, cam_to_world))  # camera-z component 1
    return np.broadcast_to(np.asarray(cam_to_world, np.float64)[:3, 3], d.shape).copy(), d


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
    dist=None,
) -> dict[str, Any]:
    """Independently traced ground truth of one view at ``frame`` towards ``frame + step``.

    ``stage_or_geometry``: a Usd.Stage or a StageGeometry; ``cam_to_world_t1`` is the view's
    pose at ``frame + step``. ``scenes`` (optional dict) caches TracedScene per time between calls.
    Returns depth (H,W; inf on background), position (H,W,3), mesh (H,W int; index into
    ``prim_paths``, -1 background), prim_paths, flow (H,W,2) to frame+step, scene_flow (H,W,3),
    disparity_change (H,W; needs ``baseline``), occluded (H,W bool: hidden or outside the image
    at frame+step), valid (H,W bool: foreground whose mesh keeps its topology) and the tracing
    context ``ctx`` that :func:`trace_pixels` takes for sub-pixel candidates. ``dist``: the view's lens
    distortion (lfusd.camera.Distortion; None: a pinhole): pixel coordinates are then distorted ones, each
    traced along the ray the lens images there, and points at the other frame imaged through it.
    """
    from ..author.geometry import StageGeometry

    geo = stage_or_geometry if isinstance(stage_or_geometry, StageGeometry) else StageGeometry(stage_or_geometry)
    scenes = {} if scenes is None else scenes
    for t in (frame, frame + step):
        if t not in scenes:
            scenes[t] = TracedScene(geo, t)
    ctx = {"s0": scenes[frame], "s1": scenes[frame + step], "K": np.asarray(K, np.float64), "c2w": np.asarray(cam_to_world_t, np.float64),
           "c2w1": np.asarray(cam_to_world_t1, np.float64), "H": H, "W": W, "baseline": baseline, "dist": dist}
    u = np.tile(np.arange(W, dtype=np.float64), H)  # the pixel centres, raster order
    v = np.repeat(np.arange(H, dtype=np.float64), W)
    out = trace_pixels(ctx, u, v, grid=True)
    full = {k: (a.reshape(H, W, *a.shape[1:]) if isinstance(a, np.ndarray) and a.shape[:1] == (H * W,) else a) for k, a in out.items()}
    full["ctx"] = ctx
    return full


def trace_pixels(ctx: dict, u: np.ndarray, v: np.ndarray, hits: tuple[np.ndarray, np.ndarray] | None = None,
                 visibility: bool = True, grid: bool = False) -> dict[str, Any]:
    """:func:`trace_motion`'s values for rays through arbitrary pixel coordinates (u, v) (flat arrays);
    ``hits`` (mesh, triangle) per ray replaces the first hit (a second surface along the ray);
    ``visibility=False`` skips the visibility cast at the other frame (``occluded`` all False);
    ``grid``: (u, v) is the view's full pixel grid (its first hits then come from
    :meth:`TracedScene.grid_hits`, and its surface is kept for the view's other direction)."""
    from . import _verify_numba as _numba  # the per-ray arithmetic, compiled

    s0, s1, K, H, W = ctx["s0"], ctx["s1"], ctx["K"], ctx["H"], ctx["W"]
    n = len(u)
    u, v = np.ascontiguousarray(u, np.float64).ravel(), np.ascontiguousarray(v, np.float64).ravel()
    key = None
    if hits is None and grid:  # a full grid: the same surface for a view's traces to t+1 and t-1
        key = (H, W, K.tobytes(), ctx["c2w"].tobytes(), repr(ctx.get("dist")))
    lens = ctx.get("dist") is not None and not ctx["dist"].is_identity
    if key is not None and s0._surface is not None and s0._surface[0] == key:
        o, mesh, tri, depth, pos, normal, bary, g = s0._surface[1]
    else:
        o = np.ascontiguousarray(ctx["c2w"][:3, 3], np.float64)  # every ray's origin: the camera centre
        A = _pixel_to_world(ctx)
        if lens:  # the lens's ray through each pixel (camera-z component 1)
            d = np.ascontiguousarray(ray_directions(u, v, _camera(ctx)), np.float64)
            mesh, tri = s0.cast(np.broadcast_to(o, (n, 3)), d)[1:] if hits is None else hits
        else:
            # directions with camera-z component 1 (lfusd.camera.ray_directions of a pinhole): A (u, v, 1),
            # computed again where needed rather than stored
            d = np.zeros((0, 3))
            if hits is not None:
                mesh, tri = hits
            elif grid:  # the view's full pixel grid: binned per triangle (TracedScene.grid_hits), not one cast per ray
                mesh, tri = s0.grid_hits(A, o, 0.0, 0.0, W, H)
            else:
                mesh, tri = s0.cast_rays(_numba.rays_through(u, v, A, o))[1:]
        mesh, tri = np.ascontiguousarray(mesh, np.int64), np.ascontiguousarray(tri, np.int64)
        depth, pos, normal, bary = np.empty(n), np.empty((n, 3)), np.empty((n, 3)), np.empty((n, 2))
        _numba.surface_from(o, d, u, v, A, mesh, tri, s0.V, s0.T, s0.tri_offset, depth, pos, normal, bary)
        g = np.flatnonzero(mesh >= 0)
        if key is not None:
            s0._surface = (key, (o, mesh, tri, depth, pos, normal, bary, g))
    cam1 = _camera(ctx, 1)
    R, C = cam1.world_to_cam()
    baseline = ctx["baseline"]
    fb = float(K[0, 0]) * float(baseline) if baseline else np.nan
    # The camera centre stays put: a first hit on a triangle that stands still is the same point on
    # the same segment from the centre as at t, where nothing lay before it; only what moved can
    # hide it now (see visibility_of).
    same_centre = visibility and hits is None and np.array_equal(ctx["c2w1"][:3, 3], ctx["c2w"][:3, 3]) and g.size > 0
    static = s0.static_triangles(s1) if same_centre else np.zeros(0, bool)
    pos1, valid, u1, v1, z1 = np.empty((n, 3)), np.empty(n, bool), np.empty(n), np.empty(n), np.empty(n)
    flow, sflow, dchange, still = np.empty((n, 2)), np.empty((n, 3)), np.empty(n), np.empty(n, bool)
    with np.errstate(divide="ignore", invalid="ignore"):
        _numba.carry_motion(mesh, tri, bary, s0.same_topology(s1), s1.V, s1.T, s1.tri_offset, np.ascontiguousarray(K @ R, np.float64),
                            np.ascontiguousarray(R[2], np.float64), np.ascontiguousarray(C, np.float64), u, v, pos, depth, fb, static,
                            s0.tri_offset, pos1, valid, u1, v1, z1, flow, sflow, dchange, still)
    if lens and g.size:  # the kernel projects through the pinhole: image the carried points through the lens
        from ..camera import project_imaged

        u1, v1, z1, imaged = project_imaged(np.where(valid[:, None], pos1, 0.0), cam1)
        valid &= imaged  # beyond the lens's fold a point has no image: its motion is not defined there
        flow = np.stack([u1 - u, v1 - v], -1)
        if baseline:  # the disparity of a distorted view (docs/CONVENTIONS.md, "Lens distortion")
            from ..camera import point_disparity

            with np.errstate(divide="ignore", invalid="ignore"):
                dchange = point_disparity(pos1, cam1, float(baseline)) - point_disparity(pos, _camera(ctx), float(baseline))
            valid &= np.isfinite(dchange)
        else:
            with np.errstate(divide="ignore", invalid="ignore"):
                dchange = fb / z1 - fb / depth
    if visibility:
        vis, t_hit = visibility_of(s1, cam1, pos1, valid, H, W, uvz=(u1, v1, z1), still=still if same_centre else None,
                                   moving=s1.moving_scene(s0) if same_centre else None)
    else:
        vis, t_hit = np.ones(n, bool), np.full(n, np.nan)
    return {
        "depth": depth, "position": pos, "normal": normal, "mesh": mesh, "triangle": tri,
        "prim_paths": s0.prim_paths,
        "mesh_bounds": s0.bounds,
        "flow": flow,
        "scene_flow": sflow,
        "next_position": pos1,
        "disparity_change": dchange,
        "occluded": valid & ~vis,
        "visibility_hit": t_hit,
        "valid": valid,
    }


def _pixel_to_world(ctx: dict) -> np.ndarray:
    """(3, 3) float64 A of the traced view's pinhole at t: the ray direction through pixel (u, v) is A (u, v, 1)."""
    return np.ascontiguousarray(Camera(ctx["K"], ctx["c2w"])._pixel_to_world(np.float64), np.float64)


def _corners(ctx: dict, u: np.ndarray, v: np.ndarray, carry: bool, grid: bool = False) -> tuple[np.ndarray, np.ndarray, np.ndarray | None]:
    """What the ``mixed`` rule reads at rays through (u, v): :func:`trace_pixels`' mesh, depth and (with
    ``carry``) flow, computed alone (no hit point, normal, scene flow or visibility kept). ``grid``: (u, v)
    is the view's full (H + 1) x (W + 1) grid of pixel corners, raster order."""
    from . import _verify_numba as _numba

    if ctx.get("dist") is not None and not ctx["dist"].is_identity:  # through a lens: the full trace
        c = trace_pixels(ctx, u, v, visibility=False)
        return c["mesh"], c["depth"], c["flow"] if carry else None
    s0, s1, K = ctx["s0"], ctx["s1"], ctx["K"]
    u, v = np.ascontiguousarray(u, np.float64), np.ascontiguousarray(v, np.float64)
    o = np.ascontiguousarray(ctx["c2w"][:3, 3], np.float64)
    A = _pixel_to_world(ctx)
    if grid:
        mesh, tri = s0.grid_hits(A, o, -0.5, -0.5, ctx["W"] + 1, ctx["H"] + 1)
    else:
        mesh, tri = s0.cast_rays(_numba.rays_through(u, v, A, o))[1:]
    R, C = _camera(ctx, 1).world_to_cam()
    depth, flow = np.empty(len(u)), np.empty((len(u) if carry else 0, 2))
    _numba.corner_motion(u, v, A, o, mesh, tri, s0.V, s0.T, s0.tri_offset, s0.same_topology(s1), s1.V, s1.T, s1.tri_offset,
                         np.ascontiguousarray(K @ R, np.float64), np.ascontiguousarray(R[2], np.float64), np.ascontiguousarray(C, np.float64),
                         carry, depth, flow)
    return mesh, depth, flow if carry else None


def _camera(ctx: dict, at: int = 0) -> Camera:
    """The traced view's camera at t (``at`` 0) or at the other frame (1), with its lens."""
    return Camera(ctx["K"], ctx["c2w1" if at else "c2w"], ctx.get("dist"))


def visibility_of(scene: "TracedScene", cam: Camera, points: np.ndarray, valid: np.ndarray, H: int, W: int,
                  eps: float = VISIBLE_EPS, uvz: tuple | None = None, still: np.ndarray | None = None,
                  moving=None) -> tuple[np.ndarray, np.ndarray]:
    """(visible, first-hit ray parameter) of world points at the scene's time: inside the image and
    no surface on the segment from the camera centre before ``1 - eps`` (lfusd.truth.visibility's rule);
    the ray parameter is exact where it decides anything (at or before ``1 - eps`` and the top of the
    occlusion tie band, 1 - VISIBLE_EPS / 10); a segment with nothing up to there gets +inf (:func:`_first_hits`);
    ``uvz``: the points' projection in ``cam`` when the caller has it. ``still`` (per point): the
    point is the first hit, at the other time, of a ray from this same camera centre, on a triangle
    that stands still, so no triangle that stands still lies before it: its segment is cast against
    ``moving`` alone (:meth:`TracedScene.moving_scene`; None: nothing moved), and only where one of
    those may lie in front of it; its own surface counts as a hit at 1."""
    from . import _verify_numba as _numba

    u1, v1, z1 = project(points, cam) if uvz is None else uvz
    C1 = np.ascontiguousarray(np.asarray(cam.cam_to_world, np.float64)[:3, 3])
    near = np.zeros((0, 0))
    if still is not None and moving is not None and still.any():
        # only where a moving triangle may lie in front: its screen rectangle (grown by a
        # pixel) covers the pixel nearest the point, nearer than the point (depth is the ray
        # parameter times the point's depth: a triangle no nearer cannot hit before 1)
        # (kept per scene for the last camera: a view's tie candidates trace through the same one)
        key = (np.asarray(cam.K, np.float64).tobytes(), np.asarray(cam.cam_to_world, np.float64).tobytes(), H, W)
        if scene._near is not None and scene._near[0] is moving and scene._near[1] == key:
            near = scene._near[2]
        else:
            mscene, V1, T1 = moving
            R, _ = cam.world_to_cam()
            near = _numba.nearest_depth(V1, T1, np.asarray(cam.K, np.float64) @ R, C1, np.ascontiguousarray(R[2], np.float64), H, W, 1.0)
            scene._near = (moving, key, near)
    f64 = lambda a: np.ascontiguousarray(a, np.float64)  # noqa: E731
    inside, t_hit, idx, rays, known, krays = _numba.visibility_split(
        f64(points), np.ascontiguousarray(valid, bool), f64(u1), f64(v1), f64(z1),
        np.zeros(0, bool) if still is None else np.ascontiguousarray(still, bool), near, H, W, C1)
    # what is decided from a first hit: visible (none before 1 - eps) and the occlusion tie band
    # (one in [1 - 10 eps, 1 - eps / 10], as verify's errors read it): a farther one is not needed
    upto = max(1 - eps, 1 - VISIBLE_EPS / 10)
    if known.size:  # picked as maybe hidden by what moved: cast at once (most are, the occlusion test would not pay)
        t_hit[known] = np.minimum(moving[0].cast_rays(_tensor(krays))["t_hit"].numpy(), 1.0)
    if idx.size:
        t_hit[idx] = _first_hits(scene.scene, rays, upto)
    with np.errstate(invalid="ignore"):
        return inside & (t_hit >= 1 - eps), t_hit


def _first_hits(scene, rays: np.ndarray, upto: float) -> np.ndarray:
    """Per ray ((N, 6) float32, as Open3D takes them) of an Open3D scene: the first hit's ray parameter
    where one lies at or before ``upto``, else +inf (or a hit just past it). Open3D's occlusion test
    (any hit up to a limit, cheaper than a cast) picks the rays to cast: a ray has a hit at or before
    a limit exactly when its first hit is."""
    far = np.nextafter(np.float32(upto), np.float32(np.inf))  # float32 at or above upto: no hit at upto is missed
    t = np.full(len(rays), np.inf, np.float32)
    sel = np.flatnonzero(scene.test_occlusions(_tensor(rays), tfar=float(far)).numpy())
    if sel.size:
        t[sel] = scene.cast_rays(_tensor(rays[sel]))["t_hit"].numpy()
    return t


def _tensor(rays: np.ndarray):
    """Rays ((N, 6) float32) as an Open3D tensor sharing their memory (no copy)."""
    import open3d as o3d

    return o3d.core.Tensor.from_numpy(np.ascontiguousarray(rays, np.float32))


# -- comparison ------------------------------------------------------------------------------


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


TIE_PX = 1e-3  # least sub-pixel offset of the candidate rays of the tie rule (an edge near the sample)
EPS32 = 2.0**-24  # float32 unit roundoff: Blender intersects rays with float32 geometry
EDGE_FRACTIONS = (1.0, 0.25, 0.0625)  # offsets (of the edge step) of the rays whose second surface is a candidate
EDGE_ULPS = 8  # an edge within this many roundoffs of the coordinates' magnitude (in px) may be either side
GRAZING_ULPS = 16  # depth error bound of a hit at incidence theta: this many roundoffs of max(|P|, |O|) / cos(theta)
GRAZING_COS = 0.1  # ... for hits beyond 84 degrees (nearer the normal the bound is far under any limit)
UNCHECKED_FRACTION = 1e-3  # verify fails when more than this fraction of the pixels lfusd calls valid cannot be checked
# Kinds of tie (a pixel over a limit that another surface or float rounding explains), counted per key:
# edge: a ray moved by the float bound of the edges near the sample sees what the dataset holds;
# surface: a second surface along the ray within VISIBLE_EPS of the distance; visibility: an occluder
# within the visibility band; grazing: a depth within the float bound at the hit's incidence;
# mixed: a mixed decision within its band.
TIE_KINDS = ("edge", "surface", "visibility", "grazing", "mixed")


@dataclass
class Row:
    """Error statistics of one key and class in one view and frame, over every pixel compared."""

    frame: int
    view: tuple[int, int]
    key: str
    label: str
    count: int  # pixels compared
    median: float
    p99: float
    max: float
    threshold: float
    over: int = 0  # pixels whose error exceeds the threshold (disagree, for masks and instances)
    foreground: int = 0  # foreground pixels of this class in the view (coverage = count / foreground)
    ties: int = 0  # pixels accepted by the tie rule (a second surface within float tolerance)
    worst: tuple | None = None  # (u, v, error) of the worst pixel
    tie_kinds: dict = field(default_factory=dict)  # ties by kind (TIE_KINDS)

    @property
    def rate(self) -> bool:
        return UNITS.get(self.key) == "frac"

    @property
    def ok(self) -> bool:
        """No pixel over the limit (the report's rule, :attr:`VerifyReport.ok`, allows a few)."""
        return self.over == 0


@dataclass
class VerifyReport:
    """All rows of a verification and the verdict (:attr:`ok`).

    A key fails when any compared pixel exceeds its limit unexplained by a tie (instance and
    occlusion: disagrees, or more than the key's limit of a class does, 0 by default); the whole
    report fails when more than
    ``UNCHECKED_FRACTION`` of the pixels the dataset calls valid could not be checked."""

    rows: list[Row] = field(default_factory=list)
    problems: list[str] = field(default_factory=list)  # views with no data to compare (missing or damaged files)
    valid: int = 0  # pixels the dataset calls valid (motion keys), over frames and views
    unchecked: int = 0  # of those, pixels the independent trace cannot check (e.g. a mesh changing topology)

    def compared(self) -> dict[str, int]:
        """Pixels compared per key (all classes together), over every frame and view."""
        out: dict[str, int] = {}
        for r in self.rows:
            if r.label == ALL:
                out[r.key] = out.get(r.key, 0) + r.count
        return out

    def _totals(self) -> dict[tuple[str, str], dict]:
        out: dict[tuple[str, str], dict] = {}
        for r in self.rows:
            e = out.setdefault((r.key, r.label), {"key": r.key, "label": r.label, "count": 0, "over": 0, "foreground": 0, "ties": 0,
                                                  "p99": 0.0, "max": 0.0, "medians": [], "threshold": r.threshold, "worst": None,
                                                  "tie_kinds": {}})
            e["count"] += r.count
            e["over"] += r.over
            e["foreground"] += r.foreground
            e["ties"] += r.ties
            for k, n in r.tie_kinds.items():
                e["tie_kinds"][k] = e["tie_kinds"].get(k, 0) + n
            if r.count:
                e["medians"].append(r.median)
                e["p99"] = max(e["p99"], r.p99)
                if r.max >= e["max"]:
                    e["max"] = r.max
                    if r.worst is not None:
                        e["worst"] = (r.frame, r.view, *r.worst)
        return out

    def key_failures(self) -> list[str]:
        """One line per failing key or class: the rule it breaks and its worst pixel."""
        out = []
        for (key, label), e in self._totals().items():
            rate = UNITS.get(key) == "frac"
            lim = e["threshold"]
            why = None
            if key.endswith(BIAS) and e["over"]:
                why = f"mean signed error {e['max']:.3g} {UNITS[key[:-len(BIAS)]]} over {e['count']} px, over the bias limit {lim:g}"
            elif key in EXACT and e["over"]:
                why = f"{e['over']} of {e['count']} px " + ("face away from the camera or are not of unit length" if key == "normal" else "disagree")
            elif not rate and label == ALL and e["over"]:
                why = f"{e['over']} of {e['count']} px over the limit {lim:g} (no tie explains them)"
            elif rate and e["count"] and e["over"] / e["count"] > lim:
                why = f"disagrees on {100 * e['over'] / e['count']:.3g} % of {e['count']} px > {100 * lim:g} %"
            if why:
                w = e["worst"]
                at = f"; worst at frame {w[0]} view {w[1][0]},{w[1][1]} pixel (u={w[2]}, v={w[3]}): error {w[4]:.3g}" if w else ""
                out.append(f"{key} ({label if label != ALL else 'all classes'}): {why}{at}")
        return out

    @property
    def ok(self) -> bool:
        """See the class docstring; a check that compared nothing has failed too."""
        return (bool(self.rows) and not self.problems and not self.key_failures() and all(self.compared().values())
                and self.unchecked <= UNCHECKED_FRACTION * self.valid)

    def failures(self) -> list[str]:
        """One line per failure: views without data, keys that compared nothing, keys and classes
        over their limits (naming the worst pixel), pixels that could not be checked."""
        if not self.rows:
            return self.problems + ["nothing to compare: the frames and views selected hold no ground truth to check; select some with --frames/--views"]
        out = list(self.problems)
        totals = self._totals()
        for key, n in self.compared().items():
            if n == 0 and totals[(key, ALL)]["foreground"] == 0:  # say what is true: no surface, not a wrong stage
                out.append(f"{key}: nothing to compare (0 px): no surface is in view in the frames and views selected, in the "
                           "dataset or in the stage; aim the rig at the scene, or select other --frames/--views")
            elif n == 0:
                out.append(f"{key}: nothing to compare (0 px over every frame and view, where {totals[(key, ALL)]['foreground']} px "
                           "show a surface); check that --stage is the rendered stage")
        out += self.key_failures()
        if self.unchecked > UNCHECKED_FRACTION * self.valid:
            out.append(f"{self.unchecked} of {self.valid} px that the dataset calls valid could not be checked "
                       f"(> {100 * UNCHECKED_FRACTION:g} %): their meshes change topology in the stage but not in the render")
        return out

    def summary(self) -> list[dict]:
        """Per key and class over all frames and views: pixels compared, coverage of the foreground,
        median of medians, worst p99 and max, pixels over the limit, ties, and whether it passes."""
        failing = {line.split(" ", 1)[0] for line in self.key_failures()}
        out = []
        for e in self._totals().values():
            e["median"] = float(np.median(e.pop("medians"))) if e["count"] else 0.0
            e["coverage"] = e["count"] / e["foreground"] if e["foreground"] else 0.0
            e["ok"] = e["key"] not in failing
            out.append(e)
        return out

    def certificate(self) -> dict:
        """The per-key figures over all classes (pixels compared, coverage, p99, max, count over the
        limit, ties) and the verdict: what a dataset records as its proof (manifest, card)."""
        summary = self.summary()
        keys = {e["key"]: {k: e[k] for k in ("count", "coverage", "p99", "max", "over", "ties", "tie_kinds", "threshold")}
                for e in summary if e["label"] == ALL}
        bias: dict[str, dict] = {}  # per key: the object of the largest bias relative to its limit
        for e in summary:
            if e["key"].endswith(BIAS) and e["count"]:
                key = e["key"][:-len(BIAS)]
                if key not in bias or e["max"] / e["threshold"] > bias[key]["max"] / bias[key]["threshold"]:
                    bias[key] = {"object": e["label"], "max": e["max"], "threshold": e["threshold"], "over": e["over"]}
        return {"ok": self.ok, "rules": {"unchecked_fraction": UNCHECKED_FRACTION, "tie_px": TIE_PX, "edge_ulps": EDGE_ULPS, "edge_fractions": list(EDGE_FRACTIONS),
                                         "grazing_ulps": GRAZING_ULPS, "visible_eps": VISIBLE_EPS,
                                         "bias_fraction": BIAS_FRACTION, "bias_min_px": BIAS_MIN_PX},
                "valid": self.valid, "unchecked": self.unchecked, "keys": keys, "bias": bias}

    def table(self) -> str:
        """Plain-text table of :meth:`summary`."""
        lines = [f"{'key':<17}{'class':<14}{'pixels':>9}{'cover':>7}{'median':>10}{'p99':>10}{'max':>10}{'over':>6}{'ties':>6}{'limit':>9}  ok"]
        for e in self.summary():
            lines.append(
                f"{e['key']:<17}{(e['label'] or 'unlabelled'):<14}{e['count']:>9}{100 * e['coverage']:>6.1f}%"
                f"{e['median']:>10.3g}{e['p99']:>10.3g}{e['max']:>10.3g}{e['over']:>6}{e['ties']:>6}{e['threshold']:>9.3g}  {'yes' if e['ok'] else 'NO'}"
            )
        return "\n".join(lines)


ALL = "(all)"


class _Errors(dict):
    """Per-key errors (key -> (N,) array) that are the rows of one (keys, N) array ``stack``, in order:
    what :func:`_over` reads in one compiled pass."""

    stack: np.ndarray


def _errors(ds: dict, idx: np.ndarray | slice, st: dict, fw: dict | None, bw: dict | None, ids: np.ndarray, thr: dict,
            classes: np.ndarray | None = None) -> dict[str, np.ndarray]:
    """Per-key error at flat pixels ``idx`` (``slice(None)``: all of them, without a copy) (NaN where
    the key is not compared there): ``ds`` holds the
    dataset's flat arrays, ``st`` a trace at t and ``fw``/``bw`` traces towards t+1 / t-1 (None: the
    frame has no neighbour that way, so the dataset must call no pixel valid that way), each
    indexed like ``idx``; ``classes``: the stage's class id of every instance id (semantic check).
    Instance, semantic, validity and occlusion errors are 0 (agree) or 1; normal: 1 - cos of the
    angle to the traced triangle's normal facing the camera (2 when not of unit length). Every
    key's pixels in one compiled pass per direction (lfusd.truth._verify_numba)."""
    from . import _verify_numba as _numba

    kinds = {"instance": np.int64, "semantic": np.int64, "valid_fwd": bool, "valid_bwd": bool, "occlusion_fwd": bool, "occlusion_bwd": bool}

    def at(key, tail=()):  # the dataset's array at the pixels (float32 or float64, int64, bool), or an empty one
        a = ds.get(key)
        kind = kinds.get(key, np.float32)
        if a is None:
            return np.zeros((0, *tail), kind)
        a = np.asarray(a if isinstance(idx, slice) else a[idx])
        if kind is np.float32 and a.dtype != np.float32:
            kind = np.float64  # one compiled variant per kind of array: what a dataset holds, or float64
        return np.ascontiguousarray(a, kind)

    d_ds = at("depth")
    n = len(d_ds)
    has_sem = ds.get("semantic") is not None and classes is not None
    has_normal = ds.get("normal") is not None and "normal" in st
    static = ["depth"] + ["instance"] * (ds.get("instance") is not None) + ["semantic"] * has_sem + ["normal"] * has_normal
    motion: list[tuple[str, dict | None, list[str]]] = []
    for name, tr in (("fwd", fw), ("bwd", bw)):
        keys = [f"valid_{name}"] * (ds.get(f"valid_{name}") is not None)
        if tr is not None:
            keys += [f"flow_{name}"] * (ds.get(f"flow_{name}") is not None)
            keys += ["scene_flow"] * (name == "fwd" and ds.get("scene_flow") is not None)
            keys += ["disparity_change"] * (name == "fwd" and ds.get("disparity_change") is not None)
            keys += [f"occlusion_{name}"] * (ds.get(f"occlusion_{name}") is not None)
        motion.append((name, tr, keys))
    order = static + [k for _, _, keys in motion for k in keys]
    E = np.empty((len(order), n))
    row = {k: E[i] for i, k in enumerate(order)}
    none = np.zeros(0)
    fg_ds, both = np.empty(n, bool), np.empty(n, bool)
    mesh = np.ascontiguousarray(st["mesh"], np.int64)
    _numba.static_errors(d_ds, mesh, np.ascontiguousarray(st["depth"], np.float64), ids, at("instance"),
                         at("semantic") if has_sem else np.zeros(0, np.int64), classes if has_sem else np.zeros(1, np.int64),
                         at("normal", (3,)) if has_normal else np.zeros((0, 3), np.float32),
                         np.ascontiguousarray(st["normal"], np.float64) if has_normal else np.zeros((0, 3)), float(BACKGROUND_DEPTH),
                         NORMAL_LENGTH_TOL, row["depth"], row.get("instance", none), row.get("semantic", none), row.get("normal", none),
                         fg_ds, both)
    for name, tr, keys in motion:
        if tr is None:
            # No neighbour frame that way (the ends of the rendered range): nothing is valid there.
            if keys:
                row[keys[0]][:] = np.where(fg_ds, at(keys[0]), np.nan)
            continue
        sf_limit = none
        if "scene_flow" in keys:
            # Held to the limit or SCENE_FLOW_REL of the object's size, whichever is smaller, but
            # never below the storage step (a 1.5 mm object's true error is the rounding).
            sf_limit = np.maximum(np.minimum(thr["scene_flow"], SCENE_FLOW_REL * object_sizes(ids, tr["mesh_bounds"])), SCENE_FLOW_FLOOR)
        f64 = lambda k, tail=(): np.ascontiguousarray(tr[k], np.float64) if k in tr else np.zeros((0, *tail))  # noqa: E731
        finite = _numba.motion_errors(
            both, np.ascontiguousarray(tr["valid"], bool), at(f"valid_{name}"), at(f"flow_{name}", (2,)), f64("flow", (2,)),
            at("scene_flow", (3,)) if "scene_flow" in keys else np.zeros((0, 3), np.float32), f64("scene_flow", (3,)), sf_limit,
            float(thr.get("scene_flow", np.nan)), mesh, ids,
            at("disparity_change") if "disparity_change" in keys else np.zeros(0, np.float32), f64("disparity_change"),
            at(f"occlusion_{name}") if f"occlusion_{name}" in keys else np.zeros(0, bool), np.ascontiguousarray(tr["occluded"], bool),
            f64("visibility_hit"), float(VISIBLE_EPS),
            row.get(f"valid_{name}", none), row.get(f"flow_{name}", none), row.get("scene_flow", none) if name == "fwd" else none,
            row.get("disparity_change", none) if name == "fwd" else none, row.get(f"occlusion_{name}", none))
        if "disparity_change" in keys and not finite:
            order.remove("disparity_change")  # a traced disparity change that is not finite: not compared
    err = _Errors((k, row[k]) for k in order)
    err.stack = E if len(order) == len(E) else None
    err.fg_ds, err.both = fg_ds, both  # where the dataset, and both it and the trace, see a surface
    return err


def _norm(a: np.ndarray) -> np.ndarray:
    """Euclidean length of each row of ``a`` (N, C) (np.linalg.norm's, in one pass)."""
    a = np.asarray(a, np.float64)
    return np.sqrt(np.einsum("ij,ij->i", a, a))


def _over(err: dict[str, np.ndarray], thr: dict) -> np.ndarray:
    """Pixels where some key's error exceeds its limit."""
    stack = getattr(err, "stack", None)
    if stack is not None and len(stack) == len(err) and all(e.base is stack and e.ctypes.data == stack[i].ctypes.data
                                                            for i, e in enumerate(err.values())):
        from . import _verify_numba as _numba

        out = np.empty(stack.shape[1], bool)
        _numba.over_any(stack, np.array([float(thr[k]) for k in err]), np.array([UNITS.get(k) == "frac" for k in err]), out)
        return out
    bad = np.zeros(next(iter(err.values())).shape, bool)
    for k, e in err.items():
        with np.errstate(invalid="ignore"):
            bad |= (e > 0.5) if UNITS.get(k) == "frac" else (e > thr[k])
    return bad


def _edge_step(ctx: dict, u: np.ndarray, v: np.ndarray, depth: np.ndarray) -> np.ndarray:
    """Per pixel, how far (px) an edge near its sample may really lie, from float32 rounding of
    coordinates of magnitude max(|P|, |O|) seen at ``depth``: never under TIE_PX."""
    C = ctx["c2w"][:3, 3]
    d = ray_directions(u, v, _camera(ctx))
    with np.errstate(invalid="ignore"):
        P = C + depth[:, None] * d
        mag = np.fmax(np.linalg.norm(P, axis=-1), np.linalg.norm(C))
        step = EDGE_ULPS * EPS32 * mag / depth * float(ctx["K"][0, 0])
    return np.where(np.isfinite(step), np.maximum(step, TIE_PX), TIE_PX)


def _second_hits(ctx: dict, u: np.ndarray, v: np.ndarray) -> tuple[np.ndarray, np.ndarray] | None:
    """Per ray through (u, v): (mesh, triangle) of a second surface within VISIBLE_EPS of the first
    hit's distance (mesh -1 where none); None when no ray has one."""
    o = np.broadcast_to(ctx["c2w"][:3, 3], (len(u), 3))
    d = ray_directions(u, v, _camera(ctx))
    ray, t, mesh, tri = ctx["s0"].all_hits(o, d)
    if ray.size == 0:
        return None
    first = np.full(len(u), np.inf)
    np.minimum.at(first, ray, t)
    alt = (t > first[ray]) & (t <= first[ray] * (1 + VISIBLE_EPS))
    if not alt.any():
        return None
    m, k = np.full(len(u), -1), np.zeros(len(u), np.int64)
    m[ray[alt]], k[ray[alt]] = mesh[alt], tri[alt]
    return m, k


def _candidates(traces: list, u: np.ndarray, v: np.ndarray, step: np.ndarray | float = TIE_PX):
    """Other surfaces a pixel's sample may have hit within float tolerance: rays offset by ``step``
    (px, per pixel: :func:`_edge_step`), a second hit along the pixel's own ray within
    VISIBLE_EPS of the first, and a second hit so near along an offset ray (the back-facing
    triangle that shares a silhouette edge: Blender's ray may meet it at the edge, and Cycles then
    negates the normal). Yields per candidate its kind (TIE_KINDS) and the traces (one per
    direction in ``traces``) at those pixels."""
    moves = ((1, 0), (-1, 0), (0, 1), (0, -1))
    for du, dv in moves:
        yield "edge", [trace_pixels(t["ctx"], u + du * step, v + dv * step) for t in traces]
    ctx = traces[0]["ctx"]
    hits = _second_hits(ctx, u, v)
    if hits is not None:
        yield "surface", [trace_pixels(t_["ctx"], u, v, hits=hits) for t_ in traces]
    for frac in EDGE_FRACTIONS:  # nearer the edge too: the back face lies within VISIBLE_EPS only there
        for du, dv in moves:
            uu, vv = u + du * frac * step, v + dv * frac * step
            hits = _second_hits(ctx, uu, vv)
            if hits is not None:
                yield "edge", [trace_pixels(t_["ctx"], uu, vv, hits=hits) for t_ in traces]


def _clear_visibility_ties(err: dict, traces: dict) -> np.ndarray:
    """Accept occlusion disagreements that are visibility ties (:func:`_visibility_tie`): set their
    error to 0 in ``err`` and return the positions accepted. ``traces``: name -> (the full trace
    with its ``ctx``, its flat values at the positions of ``err``)."""
    accepted = []
    for name, (full, t) in traces.items():
        key = f"occlusion_{name}"
        if full is None or t is None or key not in err:
            continue
        with np.errstate(invalid="ignore"):
            left = np.flatnonzero(err[key] > 0.5)
        if left.size:
            flip = _visibility_tie(full["ctx"], t, left)
            err[key][left[flip]] = 0.0
            accepted.append(left[flip])
    return np.concatenate(accepted) if accepted else np.zeros(0, np.int64)


def _clear_grazing_ties(err: dict, ds: dict, st: dict, ctx: dict, thr: dict, W: int) -> np.ndarray:
    """Accept depth errors within the float32 bound of a hit at a grazing incidence: GRAZING_ULPS
    roundoffs of max(|P|, |O|), over cos(incidence), relative to the depth (a face at 89.8 degrees
    holds its depth to about 3e-4 only). Sets their error to 0 in ``err``; returns the pixels."""
    if "depth" not in err:
        return np.zeros(0, np.int64)
    with np.errstate(invalid="ignore"):
        idx = np.flatnonzero(err["depth"] > thr["depth"])
    if idx.size == 0:
        return idx
    v, u = np.divmod(idx, W)
    d = ray_directions(u.astype(np.float64), v.astype(np.float64), _camera(ctx))
    C = ctx["c2w"][:3, 3]
    with np.errstate(invalid="ignore", divide="ignore"):
        cos = np.abs((st["normal"][idx] * d).sum(-1)) / np.linalg.norm(d, axis=-1)
        mag = np.fmax(np.linalg.norm(st["position"][idx], axis=-1), np.linalg.norm(C))
        bound = GRAZING_ULPS * EPS32 * mag / (st["depth"][idx] * cos)
        ok = (err["depth"][idx] <= bound) & (cos < GRAZING_COS)
    err["depth"][idx[ok]] = 0.0
    return idx[ok]


def _visibility_tie(ctx: dict, tr: dict, idx: np.ndarray) -> np.ndarray:
    """Whether the visibility of each traced point (flat pixels ``idx``) at the other frame changes
    when its target moves ``TIE_PX`` pixels sideways in the other frame's image (a grazing ray)."""
    cam1 = _camera(ctx, 1)
    P = tr["next_position"][idx]
    base = tr["occluded"][idx]
    _, _, z = project(P, cam1)
    R = cam1.cam_to_world[:3, :3]
    step = TIE_PX * np.abs(z)[:, None] / float(ctx["K"][0, 0])
    flip = np.zeros(idx.size, bool)
    for axis in (0, 1):
        for sign in (1, -1):
            Q = P + sign * step * R[:, axis]
            vis, _ = visibility_of(ctx["s1"], cam1, Q, tr["valid"][idx], ctx["H"], ctx["W"])
            flip |= (tr["valid"][idx] & ~vis) != base
    return flip


def compare_view(
    data: dict[str, np.ndarray | None],
    fwd: dict | None,
    bwd: dict | None,
    objects: dict,
    frame: int,
    view: tuple[int, int],
    thresholds: dict[str, float] | None = None,
    still: dict | None = None,
    counts: dict | None = None,
) -> list[Row]:
    """Error rows of one view over every pixel where the dataset or the trace sees a surface,
    silhouettes included: ``data`` holds the dataset's arrays (missing keys None), ``fwd``/``bwd``
    traces towards t+1 / t-1, or ``still`` (a trace at t alone) for a frame with neither neighbour:
    then only the static keys (depth, instance) are compared. A pixel over a limit is accepted
    when another surface its sample may have hit within float tolerance (:func:`_candidates`)
    agrees on every key (the tie rule). ``counts`` (optional dict) accumulates ``valid`` and
    ``unchecked`` pixels."""
    thr = {**THRESHOLDS, **EXACT, **(thresholds or {})}
    tr = fwd or bwd or still
    if tr is None:
        raise ValueError("compare_view needs a trace: fwd, bwd or still")
    H, W = np.asarray(data["depth"]).shape[:2]
    ids = object_ids_for(tr["prim_paths"], objects)
    classes = None
    if objects and all(getattr(o, "class_id", None) is not None for o in objects.values()):
        classes = np.zeros(max(objects) + 1, np.int64)
        for i, o in objects.items():
            classes[i] = o.class_id
    flat = lambda t: None if t is None else {k: (a.reshape(H * W, *a.shape[2:]) if isinstance(a, np.ndarray) and a.shape[:2] == (H, W) else a)
                                             for k, a in t.items()}  # noqa: E731
    ds = {k: (None if a is None else np.asarray(a).reshape(H * W, *np.asarray(a).shape[2:])) for k, a in data.items()}
    st, fw, bw = flat(tr), flat(fwd), flat(bwd)  # the dataset's arrays stay as stored: the kernels compute in float64
    err = _errors(ds, slice(None), st, fw, bw, ids, thr, classes)  # every pixel (views of the arrays, no gathers)
    kind = np.zeros(H * W, np.int8)  # ties of every key at a pixel (edge, surface): 0 none, else 1 + index in TIE_KINDS
    own: dict[str, list] = {}  # ties of one key: key -> [(pixels, kind)]
    vis = (_clear_visibility_ties(err, {"fwd": (fwd, fw), "bwd": (bwd, bw)}), 1 + TIE_KINDS.index("visibility"))
    own["occlusion_fwd"] = own["occlusion_bwd"] = [vis]
    own["depth"] = [(_clear_grazing_ties(err, ds, st, tr["ctx"], thr, W), 1 + TIE_KINDS.index("grazing"))]
    bad = np.flatnonzero(_over(err, thr))
    if bad.size:
        v, u = np.divmod(bad, W)
        traced = [t for t in (fwd, bwd, still) if t is not None]
        explained = np.zeros(bad.size, bool)  # by an earlier candidate: the first that explains a pixel counts
        near = np.where(np.isfinite(st["depth"][bad]), st["depth"][bad], ds["depth"][bad])
        step = _edge_step(tr["ctx"], u.astype(np.float64), v.astype(np.float64), near)
        for name, cand in _candidates(traced, u.astype(np.float64), v.astype(np.float64), step):
            c = dict(zip([n for n, t in (("fwd", fwd), ("bwd", bwd), ("still", still)) if t is not None], cand))
            e = _errors(ds, bad, c.get("fwd") or c.get("bwd") or c["still"], c.get("fwd"), c.get("bwd"), ids, thr, classes)
            _clear_visibility_ties(e, {"fwd": (fwd, c.get("fwd")), "bwd": (bwd, c.get("bwd"))})
            # a candidate that sees nothing where the centre saw a surface cannot explain the pixel
            fine = ~_over(e, thr) & (e["depth"] == e["depth"]) if "depth" in e else ~_over(e, thr)
            # (a pixel already accepted as an occlusion tie still needs its other keys explained)
            fine &= ~explained
            explained |= fine
            for k in err:
                if k in e:
                    err[k][bad[fine]] = e[k][fine]
            kind[bad[fine]] = 1 + TIE_KINDS.index(name)
    if ds.get("mixed") is not None and (fwd is not None or bwd is not None):  # a lone frame has no motion keys derived
        base = fwd or bwd
        err["mixed"], tied = _mixed_errors(ds["mixed"], base["ctx"], fwd is not None, ids, H, W)
        own["mixed"] = [(np.flatnonzero(tied), 1 + TIE_KINDS.index("mixed"))]
    ties = kind > 0  # pixels whose errors are another surface's
    inst_tr = ids[st["mesh"]]
    fg_ds = err.fg_ds  # the dataset sees a surface
    # The class of a pixel is the dataset's instance where it shows a labelled surface, else the trace's.
    inst_ds = ds["instance"] if ds.get("instance") is not None else inst_tr
    inst_any = np.where(fg_ds & (inst_ds > 0), inst_ds, inst_tr)
    labels_of = np.array([""] + [str(objects[i].label) for i in sorted(objects)], dtype=object)
    id_to_row = np.zeros(max([0] + list(objects) + [int(inst_any.max(initial=0))]) + 1, np.int64)
    for k, i in enumerate(sorted(objects)):
        id_to_row[i] = k + 1
    cls = id_to_row[np.clip(inst_any, 0, len(id_to_row) - 1)]
    fg = fg_ds | (st["mesh"] >= 0)
    if counts is not None:
        for name, t in (("fwd", fw), ("bwd", bw)):
            if t is not None and ds.get(f"valid_{name}") is not None:
                valid = ds[f"valid_{name}"] & fg_ds
                counts["valid"] = counts.get("valid", 0) + int(valid.sum())
                counts["unchecked"] = counts.get("unchecked", 0) + int((valid & ~t["valid"] & (st["mesh"] >= 0)).sum())
    # each pixel's label as an index into the sorted label names (no per-pixel string compares)
    names_ = sorted(set(labels_of.tolist()))
    code = np.array([names_.index(x) for x in labels_of.tolist()], np.int64)[cls]
    from . import _verify_numba as _numba

    n_labels = len(names_)
    fg_of = np.bincount(code[fg], minlength=n_labels)  # foreground pixels per label
    fg_all = int(fg.sum())
    rows: list[Row] = []
    q = np.array([50.0, 99.0])  # each row's median and p99
    for key, e in err.items():  # one compiled pass per key for every label's row
        rate = UNITS.get(key) == "frac"
        kk = kind if key != "mixed" else np.zeros_like(kind)  # this key's tie kind per pixel
        if any(len(pix) for pix, _ in own.get(key, [])):
            kk = kk.copy()
            for pix, k in own.get(key, []):
                kk[pix[kk[pix] == 0]] = k
        count, over, worst, top, total, kinds, pct = _numba.label_stats(
            np.ascontiguousarray(e, np.float64), code, kk, n_labels, len(TIE_KINDS) + 1, float(thr[key]), rate, q)
        for c in [-1] + np.flatnonzero(count[:n_labels]).tolist():
            r = n_labels if c < 0 else c
            label, fg_c = (ALL, fg_all) if c < 0 else (names_[c], int(fg_of[c]))
            if count[r] == 0:
                rows.append(Row(frame, view, key, label, 0, 0.0, 0.0, 0.0, thr[key], foreground=fg_c))
                continue
            j = int(worst[r])
            by_kind = {TIE_KINDS[k - 1]: int(n) for k, n in enumerate(kinds[r]) if k and n}
            n_ties = int(kinds[r, 1:].sum())
            if rate:
                m = float(total[r] / count[r])
                rows.append(Row(frame, view, key, label, int(count[r]), m, m, m, thr[key], int(over[r]), fg_c, n_ties,
                                (j % W, j // W, float(top[r])), by_kind))
            else:
                rows.append(Row(frame, view, key, label, int(count[r]), float(pct[r, 0]), float(pct[r, 1]), float(top[r]),
                                thr[key], int(over[r]), fg_c, n_ties, (j % W, j // W, float(top[r])), by_kind))
    rows += _bias_rows(ds, st, fw, inst_tr, ids, objects, ties, frame, view, W, thr)
    if bw is not None:
        rows += _bias_rows(ds, st, bw, inst_tr, ids, objects, ties, frame, view, W, thr, "bwd")
    return rows


def _mixed_decision(ident: np.ndarray, depth: np.ndarray, flow: np.ndarray | None, H: int, W: int,
                    depth_rel: float, flow_px: float, depth_rel2: float | None = None, flow_px2: float | None = None):
    """(H*W,) bool: lfusd.truth.visibility's mixed rule on corner hits over the (H+1) x (W+1) grid:
    the four corners differ in object (-1: a miss), in depth by more than ``depth_rel``, or (with
    ``flow``) in forward flow by more than ``flow_px``. With ``depth_rel2`` and ``flow_px2``: the
    decisions under both sets of limits, from one pass."""
    from . import _verify_numba as _numba

    out, out2 = np.zeros(H * W, bool), np.zeros(H * W, bool)
    f = np.zeros((0, 2)) if flow is None else np.ascontiguousarray(flow, np.float64)
    two = depth_rel2 is not None
    _numba.mixed_decisions(np.ascontiguousarray(ident, np.int64), np.ascontiguousarray(depth, np.float64), f, flow is not None, H, W,
                           float(depth_rel), float(flow_px), out, float(depth_rel2 if two else depth_rel),
                           float(flow_px2 if two else flow_px), out2)
    return (out, out2) if two else out


def _mixed_errors(mixed: np.ndarray, ctx: dict, carry: bool, ids: np.ndarray, H: int, W: int) -> tuple[np.ndarray, np.ndarray]:
    """(error 0/1 per pixel, tie per pixel) of the dataset's ``mixed`` against the rule decided on
    verify's own rays through the pixel corners (the trace at t, carried to t+1 when ``carry``).
    Either value is accepted where the decision changes within MIXED_BAND of its limits, or where
    a corner's ray moved TIE_PX sees another object, or a depth or flow that differs from the
    corner's by more than the rule's lower limits (a corner on an edge, the same object's
    included: a fold of a person in front of its own body). The footprint's edges
    (lfusd.truth.footprint) are decided from the stage's triangles twice: surely (squares shrunk
    by the float bound of the edge's position, a triangle within rounding of edge-on no
    silhouette, depth slack 0.8 times the rule's) and maybe (grown, either side, 1.25 times)."""
    from .visibility import MIXED_DEPTH_REL, MIXED_FLOW_PX

    uc = np.tile(np.arange(W + 1, dtype=np.float64) - 0.5, H + 1)  # the (H+1) x (W+1) corners, raster order
    vc = np.repeat(np.arange(H + 1, dtype=np.float64) - 0.5, W + 1)
    c_mesh, c_depth, flow = _corners(ctx, uc, vc, carry, grid=True)
    ident = np.where(c_mesh >= 0, ids[c_mesh], -1)
    lo, hi = MIXED_BAND
    surely, maybe = _mixed_decision(ident, c_depth, flow, H, W, MIXED_DEPTH_REL * hi, MIXED_FLOW_PX * hi,
                                    MIXED_DEPTH_REL * lo, MIXED_FLOW_PX * lo)
    # the footprint's edges, from the stage's own triangles: surely crossed (squares shrunk by the
    # float bound, nearly edge-on triangles no silhouette), or maybe (grown, edge-on either side)
    T, mesh, table = ctx["s0"].edges()
    lens = ctx.get("dist") is not None and not ctx["dist"].is_identity
    if len(T) and not lens:  # through a lens straight edges image as curves: the corner rule alone (CONVENTIONS, lens distortion)
        from .footprint import crossed_by_edges

        cam, inst = Camera(ctx["K"], ctx["c2w"]), ids[mesh]
        for out, grow, strict, rel in ((surely, -TIE_PX, True, MIXED_DEPTH_REL * lo), (maybe, TIE_PX, False, MIXED_DEPTH_REL * hi)):
            out |= crossed_by_edges(ctx["s0"].V, T, inst, table, cam, c_depth, H, W, rel, grow=grow, ulps=EDGE_ULPS,
                                    strict=strict, fpx=float(ctx["K"][0, 0])).ravel()
    got = np.asarray(mixed, bool)
    wrong = (got & ~maybe) | (~got & surely)
    tie = (surely != maybe) & (got == maybe)
    bad = np.flatnonzero(wrong)
    if bad.size:  # corners on an edge: TIE_PX away, another object, or a depth or flow step the rule counts
        wc = W + 1
        a = (bad // W) * wc + bad % W
        corners = np.unique(np.concatenate([a, a + 1, a + wc, a + wc + 1]))
        moved = np.zeros(len(uc), bool)
        z0 = c_depth[corners]
        for du, dv in ((TIE_PX, 0), (-TIE_PX, 0), (0, TIE_PX), (0, -TIE_PX)):
            m_mesh, m_depth, m_flow = _corners(ctx, uc[corners] + du, vc[corners] + dv, carry)
            step = np.where(m_mesh >= 0, ids[m_mesh], -1) != ident[corners]
            with np.errstate(invalid="ignore"):
                step |= np.abs(m_depth - z0) > MIXED_DEPTH_REL * lo * np.fmin(m_depth, z0)
                if carry:
                    step |= np.linalg.norm(m_flow - flow[corners], axis=-1) > MIXED_FLOW_PX * lo
            moved[corners] |= step
        edge = moved[a] | moved[a + 1] | moved[a + wc] | moved[a + wc + 1]
        wrong[bad[edge]] = False
        tie[bad[edge]] = True
    return wrong.astype(float), tie


def _bias_rows(ds: dict, st: dict, tr: dict | None, inst: np.ndarray, ids: np.ndarray, objects: dict, ties: np.ndarray,
               frame: int, view: tuple[int, int], W: int, thr: dict, name: str = "fwd") -> list[Row]:
    """One row per object and motion key (``<key>_bias``, labelled with the object's prim path):
    the norm of the mean signed error over the object's compared pixels (ties left out: their
    trace is another surface), against BIAS_FRACTION of the key's limit. A constant offset far
    under the per-pixel limit (a whole car's flow 0.04 px off) fails here."""
    if tr is None:
        return []
    keys = [k for k in BIAS_KEYS if ds.get(k) is not None and (k.endswith(name) or (name == "fwd" and not k.startswith("flow")))]
    if not keys:
        return []
    d_ds = ds["depth"]
    ok = np.isfinite(d_ds) & (d_ds < BACKGROUND_DEPTH) & (st["mesh"] >= 0) & tr["valid"] & ~ties & (inst > 0)
    if ds.get(f"valid_{name}") is not None:
        ok &= ds[f"valid_{name}"]
    if not ok.any():
        return []
    from . import _verify_numba as _numba

    sizes = object_sizes(ids, tr["mesh_bounds"])
    rows = []
    n_obj = int(inst.max(initial=0)) + 1
    pix = np.flatnonzero(ok)
    first = np.zeros(n_obj, np.int64)  # each object's first pixel (where its row points)
    first[inst[pix[::-1]]] = pix[::-1]
    means: dict[str, tuple[np.ndarray, np.ndarray]] = {}
    n = np.zeros(n_obj, np.int64)
    for key in keys:  # one compiled pass per key: per object, the sum of the differences
        trace_key = "flow" if key.startswith("flow") else key
        a, b = np.asarray(ds[key]), np.asarray(tr[trace_key], np.float64)
        a = a if a.dtype == np.float32 else a.astype(np.float64)  # float32 as stored (the kernel subtracts in float64)
        a, b = a.reshape(len(a), -1), b.reshape(len(b), -1)
        sums, n, broken = np.zeros((n_obj, a.shape[1])), np.zeros(n_obj, np.int64), np.zeros(n_obj, bool)
        _numba.object_sums(ok, np.ascontiguousarray(inst, np.int64), np.ascontiguousarray(a), np.ascontiguousarray(b), n_obj, sums,
                           n, broken)
        means[key] = (np.linalg.norm(sums / np.maximum(n, 1)[:, None], axis=-1), ~broken)
    objects_here = [o for o in np.flatnonzero(n >= BIAS_MIN_PX).tolist() if o in objects]
    for obj in objects_here:
        for key in keys:
            bias_of, finite = means[key]
            if not finite[obj]:
                continue
            bias = float(bias_of[obj])
            limit = BIAS_FRACTION * thr[key]
            if key == "scene_flow":
                limit = max(BIAS_FRACTION * min(thr[key], SCENE_FLOW_REL * sizes[obj]), SCENE_FLOW_FLOOR)
            j = int(first[obj])
            rows.append(Row(frame, view, key + BIAS, objects[obj].prim_path, int(n[obj]), bias, bias, bias, limit,
                            int(bias > limit), int(n[obj]), 0, (j % W, j // W, bias)))
    return rows


# -- datasets --------------------------------------------------------------------------------

# The dataset's keys that verification reads and a dataset with motion must hold (``mixed``, in
# CHECKED, is compared where present: datasets derived before it lack it; a camera effect's keys,
# such as ``blur``, are not ground truth to trace).
KEYS = ("depth", "instance", *(k for k in names(MOTION) if k != "mixed" and KEY_TABLE[k].effect is None))


# Keys checked when the dataset holds them: the normal's side, the semantic class, mixed.
CHECKED = ("normal", "semantic", "mixed")
MAX_LINES = 5  # record problems of one kind named one by one; the rest counted


def _table_problems(ds, objects: dict, class_names: list[str]) -> list[str]:
    """The dataset's object table (``objects.json``) against the stage's (``objects``: id ->
    ObjectEntry; ``class_names``): every id, prim path, label and class id must agree."""
    fix = "objects.json does not describe the stage: restore it, or render again into a new folder"
    out = []
    theirs = ds.objects
    for i in sorted(set(objects) | set(theirs)):
        a, b = theirs.get(i), objects.get(i)
        if b is None:
            out.append(f"objects.json: object {i} ({a.prim_path}) is not an object of the stage; {fix}")
        elif a is None:
            out.append(f"objects.json: object {i} ({b.prim_path}) of the stage is missing; {fix}")
        elif a.prim_path != b.prim_path:
            out.append(f"objects.json: object {i} is {a.prim_path}, the stage's object {i} is {b.prim_path}; {fix}")
        elif a.label != b.label or getattr(a, "class_id", b.class_id) != b.class_id:
            out.append(f"objects.json: object {i} ({b.prim_path}) is labelled {a.label!r} (class {getattr(a, 'class_id', '?')}), "
                       f"the stage labels it {b.label!r} (class {b.class_id}); {fix}")
    mine = getattr(ds, "classes", None)
    if mine is not None and list(mine) != list(class_names):
        out.append(f"objects.json: the class table {list(mine)} is not the stage's {list(class_names)}; {fix}")
    return out[:MAX_LINES] + ([f"objects.json: {len(out) - MAX_LINES} more objects disagree with the stage"] if len(out) > MAX_LINES else [])


def _same(a, b) -> bool:
    """Two record values equal, numbers to 1e-9 relative."""
    if isinstance(a, (list, tuple)) and isinstance(b, (list, tuple)):
        return len(a) == len(b) and all(_same(x, y) for x, y in zip(a, b))
    if isinstance(a, (int, float)) and isinstance(b, (int, float)) and not isinstance(a, bool):
        return bool(np.isclose(a, b, rtol=1e-9, atol=0))
    return a == b


def _stage_rig(stage, ds, problems: list[str]):
    """The stage's rig of the dataset (``ds.rig_name``), its spec checked against the manifest's
    (resolution aside: ``--resolution`` may override it); None for a reader without a rig record."""
    from ..author.rigs import rigs

    name, spec = getattr(ds, "rig_name", None), getattr(ds, "rig", None)
    if name is None or spec is None:
        return None
    found = rigs(stage).get(name)
    if found is None:
        problems.append(f"manifest rig {name}: the stage has no rig {name!r} to check it against; pass the rendered stage with --stage")
        return None
    a, b = spec.to_dict(), found.spec.to_dict()
    for k in sorted((set(a) | set(b)) - {"width", "height"}):
        if not _same(a.get(k), b.get(k)):
            problems.append(f"manifest rig {name}: {k} is {a.get(k)!r} but the stage's rig says {b.get(k)!r}; "
                            "the manifest does not describe the render: restore it, or render again into a new folder")
    return found


def _checked_intrinsics(rig, ds, view, K: np.ndarray, W: int, H: int, problems: list[str], seen: set) -> np.ndarray:
    """The stage rig's K at the rendered resolution; a problem line when the manifest's differs."""
    from dataclasses import replace

    Ks = replace(rig.spec, width=W, height=H).intrinsics()
    if not np.allclose(K, Ks, rtol=1e-9, atol=1e-9) and ("K", tuple(view)) not in seen:
        seen.add(("K", tuple(view)))
        problems.append(f"manifest rig {rig.spec.name} view {view[0]},{view[1]}: intrinsics {K.tolist()} are not the stage rig's "
                        f"{Ks.tolist()}; the manifest does not describe the render: restore it, or render again into a new folder")
    return Ks


POSE_TOL = 1e-6  # m (and rad): a recorded pose that differs from the stage's camera by more is wrong


def _checked_pose(stage, rig, ds, frame: int, view, problems: list[str], seen: set) -> np.ndarray:
    """The stage camera's pose of ``view`` at ``frame``; a problem line when frame.json's differs."""
    P = rig.cam_to_world(stage, tuple(view), frame)
    try:
        mine = np.asarray(ds.cam_to_world(frame, view), np.float64)
    except (FileNotFoundError, KeyError, LfusdError):
        return P  # a frame not rendered: its absence is reported where it is read
    off = float(np.abs(mine - P).max())
    if off > POSE_TOL and (frame, tuple(view)) not in seen:
        seen.add((frame, tuple(view)))
        problems.append(f"frame {frame} view {view[0]},{view[1]}: frame.json's cam_to_world differs from the stage's camera by {off:.3g}; "
                        "the record does not describe the render: restore it, or render again into a new folder")
    return P


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
    record = getattr(ds, "record", None)  # a Dataset's typed manifest (lfusd.data.folder.Manifest)
    return (record.stage or {}).get("path") if record is not None else None


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
    comes from ``stage_path``, ``ds.stage_path`` or ``ds.record.stage['path']``; ``baseline`` (or ``ds.baseline``) enables
    the disparity-change check. ``progress(frame, view)`` is called before each view.
    """
    from ..processes import one_blas_thread

    with one_blas_thread():
        return _verify_dataset(ds, stage_path, frames, views, thresholds, baseline, progress)


def _verify_dataset(ds, stage_path, frames, views, thresholds, baseline, progress) -> VerifyReport:
    from ..author.geometry import StageGeometry
    from ..author.labels import object_table
    from ..author.stage import open_stage

    stage_path = stage_path or dataset_stage_path(ds)
    if not stage_path:
        raise LfusdError("verify needs the stage the dataset was rendered from; pass --stage PATH")
    stage = open_stage(stage_path)
    geo = StageGeometry(stage)
    report = VerifyReport()
    # The records against the stage: the object table (ids, paths, labels, classes) and the rig
    # (its spec, intrinsics and every pose). The trace takes the stage's own values, not the records'.
    table, class_names = object_table(stage)
    objects = {e.instance_id: e for e in table}
    report.problems += _table_problems(ds, objects, class_names)
    rig = _stage_rig(stage, ds, report.problems)
    if baseline is None:
        baseline = rig.spec.baseline if rig is not None else getattr(ds, "baseline", None)
    # Every frame the manifest lists, complete or not: a view missing there is a failure, not a skip.
    record = getattr(ds, "record", None)  # a Dataset's typed manifest; analytic fakes have none
    all_frames = sorted(int(f) for f in (record.frames if record is not None else ()) or ds.frames)
    expect_motion = record is not None and record.settings.motion
    frames = all_frames if frames is None else [int(f) for f in frames]
    views = list(ds.views) if views is None else [tuple(v) for v in views]
    for f in frames:
        if f not in all_frames:
            raise LfusdError(f"frame {f} is not in the dataset (frames {all_frames[0]}-{all_frames[-1]}); pick one of its frames")
    for v in views:
        if tuple(v) not in [tuple(x) for x in ds.views]:
            raise LfusdError(f"view {v[0]},{v[1]} is not in the dataset; pick one of its views")
    scenes: dict = {}
    rig_checked: set = set()
    counts: dict = {}
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
            data = {k: _read_optional(ds, f, view, k) for k in KEYS + CHECKED}
            lacking = [k for k in KEYS[2:] if data[k] is None]
            if expect_motion and lacking:
                report.problems.append(f"{where}: no {', '.join(lacking)} to compare ({MOTION_FILE} missing or damaged); "
                                       "rerun render-video or 'lfusd derive' to repair it")
            H, W = np.asarray(data["depth"]).shape[:2]
            K = np.asarray(ds.intrinsics(view), np.float64)
            pose = lambda g: np.asarray(ds.cam_to_world(g, view), np.float64)  # noqa: E731
            if rig is not None:
                K = _checked_intrinsics(rig, ds, view, K, W, H, report.problems, rig_checked)
                pose = lambda g: _checked_pose(stage, rig, ds, g, view, report.problems, rig_checked)  # noqa: E731
            c2w = pose(f)
            dist = ds.distortion(view) if hasattr(ds, "distortion") else None  # --lens: traced through the view's lens
            fwd = bwd = None
            if f + 1 in all_frames:
                fwd = trace_motion(geo, f, K, c2w, pose(f + 1), H, W, 1, baseline, scenes, dist)
            if f - 1 in all_frames:
                bwd = trace_motion(geo, f, K, c2w, pose(f - 1), H, W, -1, baseline, scenes, dist)
            # A frame without rendered neighbours has no motion keys to check: its static keys are.
            still = trace_motion(geo, f, K, c2w, c2w, H, W, 0, baseline, scenes, dist) if fwd is None and bwd is None else None
            report.rows.extend(compare_view(data, fwd, bwd, objects, f, tuple(view), thresholds, still=still, counts=counts))
            for t in [t for t in scenes if t < f - 1]:
                del scenes[t]  # frames are visited in order: free meshes no longer needed
    report.valid, report.unchecked = counts.get("valid", 0), counts.get("unchecked", 0)
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
    from ..data import dataset

    unknown = sorted(set(thresholds or {}) - set(THRESHOLDS))
    if unknown:
        raise LfusdError(f"unknown threshold {unknown[0]!r}; use one of {', '.join(THRESHOLDS)}")
    from ..data.integrity import check_dataset

    reports = {}
    for ds in dataset.open_datasets(out, rig):
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


def record_certificate(out, reports: dict) -> dict:
    """Write verify's figures into the dataset's manifest (``certificate``: per rig, the per-key
    pixels compared, coverage, p99, max, count over the limit, ties, the verdict, and their binding
    to the content, lfusd.data.certificate), so the dataset carries its own proof. Returns the certificate. Call it while holding the folder."""
    from dataclasses import replace
    from pathlib import Path

    from ..data.folder import atomic_write, read_manifest
    from ..layout import MANIFEST

    from ..data.certificate import bind

    manifest = read_manifest(out)
    # bound to the content it measured (lfusd.data.certificate): re-checked before it is republished
    cert = {name: bind(out, name, rep.certificate()) for name, rep in reports.items() if name}
    atomic_write(Path(out) / MANIFEST, replace(manifest, certificate={**(manifest.certificate or {}), **cert}).to_json())
    return cert

"""Exact visibility of surface points: rays cast against a frame's triangles as Blender rendered them.

A point P seen at frame t is *visible* at frame t' (= t+1 or t-1) in a view when it projects
inside that view's image at t' (u' in [-0.5, W-0.5], v' in [-0.5, H-0.5], in front of the camera)
and the ray from the view's camera centre C' at t' towards P meets no surface before P: Open3D's
``RaycastingScene`` tests it against every rendered triangle at t' (``geometry.npz``, written by
the render worker from Blender's evaluated meshes) and finds no hit before ray parameter
``1 - VISIBLE_EPS`` (the parameter of P itself is 1). That is Embree's any-hit query
(``test_occlusions`` with tfar = 1 - VISIBLE_EPS), the same answer as "the first hit lies at or
beyond 1 - VISIBLE_EPS" without finding the first hit (measured: the same mask on 2 x 56,000 rays of
benchmarks/bench_flow.py's scene at 256x256; 120 against 139 ms of CPU per 1M rays).

Tie rule: a surface within ``VISIBLE_EPS`` (1e-4) of the distance in front of P does not hide
it. Float32 positions and triangles put P a few 1e-7 of the distance off its own surface, more on
surfaces seen at a grazing angle, and the verifier's independent geometry differs from Blender's by
as much: within that band the two surfaces cannot be told apart, and both verify and the
derivation call the point visible. docs/CONVENTIONS.md ("Occlusion") states the definition.

The cast is split without changing an answer (:class:`Parts`, :class:`StaticMemo`). A segment
meets the frame's triangles when it meets those that stand still from t to t' (static) or the
others (dynamic). A static segment's answer against static triangles cannot change while the camera
and those triangles stay put, so a derivation process keeps it per view and casts only the
segments it has not seen bit for bit (the wall behind a walking person: about 80 % of the rays
of the default scene). The dynamic triangles are cast only for segments that reach, at or beyond
their depth, the screen rectangle of one of them (a conservative z-buffer of rectangles grown by
a pixel). ``mixed`` splits its corner rays the same way: the nearer of the static first hit (kept)
and the dynamic one. tests/truth/test_static_parts.py holds every pixel to the whole scene's cast.
"""

from __future__ import annotations

import itertools
import os
from collections import OrderedDict
from pathlib import Path

import numpy as np

from ..camera import Camera

VISIBLE_EPS = 1e-4

_CACHE: dict[tuple, "Occluders"] = {}
_NEW = itertools.count()  # keys of Occluders built in memory (not read from a file)


def _scene(vertices: np.ndarray, triangles: np.ndarray):
    import open3d as o3d

    scene = o3d.t.geometry.RaycastingScene()
    if len(triangles):
        scene.add_triangles(o3d.core.Tensor(vertices), o3d.core.Tensor(np.ascontiguousarray(triangles, np.uint32)))
    return scene


class Occluders:
    """A frame's triangles (world space) in an Open3D ray-casting scene."""

    def __init__(self, vertices: np.ndarray, triangles: np.ndarray, instance: np.ndarray | None = None, key=None):
        self.vertices = np.ascontiguousarray(vertices, np.float32)
        self.triangles = np.ascontiguousarray(triangles, np.uint32)
        self.instance = instance
        self.key = key if key is not None else ("memory", next(_NEW))
        self._scene = None
        self._parts: OrderedDict = OrderedDict()

    @classmethod
    def load(cls, path: str | Path) -> "Occluders":
        """Read ``geometry.npz`` (cached per process by file identity: the views of one chunk share
        one file through hard links, so their scene is built once)."""
        st = os.stat(path)
        key = (st.st_dev, st.st_ino, st.st_size, st.st_mtime_ns)
        if key not in _CACHE:
            with np.load(path) as z:
                occ = cls(z["vertices"], z["triangles"], z["instance"] if "instance" in z else None, key=key)
            if len(_CACHE) >= 4:  # frames t-1, t, t+1 of one view, and one more
                _CACHE.pop(next(iter(_CACHE)))
            _CACHE[key] = occ
        return _CACHE[key]

    @property
    def scene(self):
        """Every triangle in one Open3D ``RaycastingScene`` (built on first use)."""
        if self._scene is None:
            self._scene = _scene(self.vertices, self.triangles)
        return self._scene

    @property
    def corners(self) -> np.ndarray:
        """(M, 3, 3) float32: each triangle's three vertices (built once)."""
        if getattr(self, "_corners", None) is None:
            self._corners = self.vertices[self.triangles.astype(np.int64)]
        return self._corners

    @property
    def edges(self) -> dict:
        """The welded triangles' edge table (lfusd.truth.footprint.edge_table; built once)."""
        if getattr(self, "_edges", None) is None:
            from .footprint import edge_table

            self._edges = edge_table(self.vertices, self.triangles)
        return self._edges

    def parts(self, other: "Occluders") -> "Parts":
        """These triangles split by ``other`` (a neighbouring frame's): see :class:`Parts`."""
        if other.key not in self._parts:
            if len(self._parts) >= 2:
                self._parts.popitem(last=False)
            self._parts[other.key] = Parts(self, other)
        return self._parts[other.key]

    def cast(self, origins: np.ndarray, dirs: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(t_hit, triangle index (-1 where none), barycentric (u, v) of the hit) per ray."""
        import open3d as o3d

        rays = np.ascontiguousarray(np.concatenate([origins, dirs], axis=-1), np.float32)
        ans = self.scene.cast_rays(o3d.core.Tensor(rays))
        t = ans["t_hit"].numpy()
        tri = np.where(np.isfinite(t), ans["primitive_ids"].numpy().astype(np.int64), -1)
        return t, tri, ans["primitive_uvs"].numpy()

    def first_hit(self, origins: np.ndarray, targets: np.ndarray) -> np.ndarray:
        """Ray parameter of the first surface on the segment origin -> target (1 = at the target;
        inf when nothing is hit)."""
        import open3d as o3d

        if len(origins) == 0:
            return np.zeros(0, np.float32)
        rays = np.concatenate([origins, targets - origins], axis=-1).astype(np.float32)
        return self.scene.cast_rays(o3d.core.Tensor(np.ascontiguousarray(rays)))["t_hit"].numpy()


_STATIC: OrderedDict = OrderedDict()  # digest of static triangles -> their scene, shared by a process's views and frames


class Parts:
    """A frame's triangles split in two by a neighbouring frame's (same triangles in the same order):
    *static*, whose three vertices are the same there bit for bit, and *dynamic*, the rest (all of
    them when the two frames' triangles differ). A ray meets the frame's triangles when it meets a
    part, so the parts give the answers of the whole: the static part's scene and answers can be
    kept from frame to frame (:class:`StaticMemo`; ``digest`` names the static triangles and their
    coordinates), and the dynamic part is small, and cast only where its triangles lie on screen."""

    def __init__(self, occ: Occluders, other: Occluders):
        import xxhash

        tri = occ.triangles
        if (len(tri) and tri.shape == other.triangles.shape and occ.vertices.shape == other.vertices.shape
                and np.array_equal(tri, other.triangles)):
            same = (occ.vertices.view(np.uint32) == other.vertices.view(np.uint32)).all(axis=1)
            static = same[tri].all(axis=1)
        else:
            static = np.zeros(len(tri), bool)
        self.static_ids = np.flatnonzero(static).astype(np.uint32)
        self.dynamic_ids = np.flatnonzero(~static).astype(np.uint32)
        h = xxhash.xxh3_128()
        h.update(self.static_ids.tobytes())
        h.update(np.ascontiguousarray(occ.corners[static]).tobytes())
        self.digest = h.hexdigest()
        self.static = None
        if len(self.static_ids):
            if self.digest not in _STATIC:
                if len(_STATIC) >= 2:
                    _STATIC.popitem(last=False)
                _STATIC[self.digest] = _scene(occ.vertices, tri[static])
            self.static = _STATIC[self.digest]
            _STATIC.move_to_end(self.digest)
        self.vertices, self.dynamic_triangles = occ.vertices, np.ascontiguousarray(tri[~static])
        self.dynamic = _scene(occ.vertices, self.dynamic_triangles) if len(self.dynamic_ids) else None


class StaticMemo:
    """One view's answers from the static triangles (:class:`Parts`), kept between frames: a ray
    that is the same bit for bit as before (same camera centre and end point; the same static
    triangles, by digest) has the same answer, so only new rays are cast. Exact by construction:
    what it returns is what the cast would return."""

    def __init__(self, nbytes: int):
        self.nbytes = nbytes  # what it may hold (its share of MEMO_BYTES)
        self.segments: dict | None = None  # visibility: key, end points (uint32 bits), filled, hidden per pixel
        self.corners: dict | None = None  # mixed: key, t, triangle and barycentric (u, v) per pixel corner


def _memo_bytes() -> int:
    try:
        memory = os.sysconf("SC_PAGE_SIZE") * os.sysconf("SC_PHYS_PAGES")
    except (ValueError, OSError, AttributeError):
        memory = 16 << 30
    return min(2 << 30, memory // 16)


# per process, for the views of one dataset (a lane's views, or a derivation task's): 2 GiB, or a
# 16th of the machine's memory where that is less (a 9x9 rig at 1024x1024 needs 2.3 GB for all views)
MEMO_BYTES = _memo_bytes()
MEMO_BYTES_PER_PIXEL = 12 + 1 + 1 + 4 + 4 + 8  # end point, filled, hidden; corner t, triangle, (u, v)
_MEMOS: OrderedDict = OrderedDict()


def memo_for(key: tuple, h: int, w: int) -> StaticMemo | None:
    """The :class:`StaticMemo` of one view (``key``: dataset, rig, view), or None when the process's
    :data:`MEMO_BYTES` are spoken for. A rig's views come in turn, frame after frame: a memo that
    dropped the least recently used would never be found again, so those held stay held, and only
    another dataset's are dropped for room."""
    if key in _MEMOS:
        return _MEMOS[key]
    need = MEMO_BYTES_PER_PIXEL * (h + 1) * (w + 1)
    if sum(m.nbytes for m in _MEMOS.values()) + need > MEMO_BYTES:
        for other in [k for k in _MEMOS if k[:-1] != key[:-1]]:
            del _MEMOS[other]
        if sum(m.nbytes for m in _MEMOS.values()) + need > MEMO_BYTES:
            return None
    _MEMOS[key] = StaticMemo(need)
    return _MEMOS[key]


def forget_memos() -> None:
    """Drop every view's :class:`StaticMemo` (a derivation task that will not see its view again)."""
    _MEMOS.clear()


# the dynamic triangles' screen rectangles are grown by this much, and their depths lowered: far
# beyond float32 rounding of the rays, the vertices and Embree's hits, so no ray that meets one is culled
MARGIN_PX = 1.0
DEPTH_REL = 1e-3


def _occluded(scene, rays: np.ndarray, eps: float) -> np.ndarray:
    import open3d as o3d

    if not len(rays):
        return np.zeros(0, bool)
    return scene.test_occlusions(o3d.core.Tensor.from_numpy(np.ascontiguousarray(rays)), tnear=0.0, tfar=1.0 - eps).numpy() != 0


def _depth_map(parts: Parts, camera: Camera, h: int, w: int) -> np.ndarray:
    """The dynamic part's conservative least depth per pixel in ``camera`` (lfusd.truth._motion_numba.depth_map)."""
    from ._motion_numba import depth_map

    R, C = camera.world_to_cam()
    return depth_map(parts.vertices, parts.dynamic_triangles, np.asarray(camera.K, np.float64) @ R,
                     np.ascontiguousarray(C, np.float64), np.ascontiguousarray(R[2], np.float64), h, w, MARGIN_PX, DEPTH_REL)


def _visible_parts(points: np.ndarray, valid: np.ndarray, camera: Camera, h: int, w: int, parts: Parts, eps: float,
                   memo: StaticMemo) -> tuple[np.ndarray, np.ndarray]:
    """:func:`visible`'s rays by part, with a memo that holds answers for these segments' camera and
    static triangles: (index of the points inside, whether a part hides each)."""
    from ._motion_numba import remember_answers, segment_parts

    R, C = camera.world_to_cam()
    seg = memo.segments
    zmap = _depth_map(parts, camera, h, w) if parts.dynamic is not None else np.zeros((0, 0), np.float32)
    bits = points.view(np.uint32)
    index, hidden, s_rays, s_pos, d_rays, d_pos = segment_parts(
        points, bits, valid, np.asarray(camera.K, np.float64) @ R, np.ascontiguousarray(C, np.float64),
        np.ascontiguousarray(R[2], np.float64), h, w, seg["ends"], seg["filled"], seg["hidden"], zmap, parts.static is not None)
    if len(s_pos):
        try:
            fresh = _occluded(parts.static, s_rays, eps)
        except BaseException:
            memo.segments = None  # its slots took these end points already: their answers never came
            raise
        remember_answers(index, s_pos, fresh, hidden, seg["hidden"])
    if len(d_pos):
        hidden[d_pos] |= _occluded(parts.dynamic, d_rays, eps)
    return index, hidden


def visible(points: np.ndarray, valid: np.ndarray, camera: Camera, h: int, w: int, occluders: Occluders,
            eps: float = VISIBLE_EPS, parts: Parts | None = None, memo: StaticMemo | None = None) -> np.ndarray:
    """Whether each world point (N,3) with ``valid`` (N,) is visible in ``camera`` at the occluders'
    frame (see the module docstring): it projects inside the image, in front of the camera, and no
    surface lies on the segment from the camera centre before ray parameter ``1 - eps`` (Embree's
    any-hit query, Open3D's ``test_occlusions``: the first hit is not needed, only whether one is
    that near). With ``parts`` (the occluders split by a neighbouring frame) and a ``memo``, the
    segment is tested against each part, the static one's answers kept in the memo between frames,
    the dynamic one's only for the segments its triangles' screen rectangles reach: the same answers
    as the whole scene's. A memo with nothing for this camera and these static triangles is filled
    from one cast against the whole scene."""
    from ._motion_numba import remember_visible, segment_rays

    points = np.ascontiguousarray(points, np.float32).reshape(-1, 3)
    valid = np.ascontiguousarray(valid).ravel()
    out = np.zeros(len(points), bool)
    R, C = camera.world_to_cam()
    if camera.dist is not None and not camera.dist.is_identity:
        return _visible_through_lens(points, valid, camera, h, w, occluders, eps)
    split = parts is not None and memo is not None and len(occluders.triangles) > 0
    if split:
        key = (parts.digest, np.asarray(C, np.float64).tobytes(), float(eps), len(points))
        if memo.segments is not None and memo.segments["key"] == key:
            index, hidden = _visible_parts(points, valid, camera, h, w, parts, eps, memo)
            out[index] = ~hidden
            return out
    rays, index = segment_rays(points, valid, np.asarray(camera.K, np.float64) @ R, np.ascontiguousarray(C, np.float64),
                               np.ascontiguousarray(R[2], np.float64), h, w)
    # the rays of the points inside only
    hidden = _occluded(occluders.scene, rays, eps) if len(occluders.triangles) else np.zeros(len(index), bool)
    if split:  # nothing to reuse: the whole scene's unhidden segments fill the memo (one cast is cheaper than two parts)
        n = len(points)
        memo.segments = {"key": key, "ends": np.zeros((n, 3), np.uint32), "filled": np.zeros(n, bool), "hidden": np.zeros(n, bool)}
        remember_visible(index, hidden, points.view(np.uint32), memo.segments["ends"], memo.segments["filled"], memo.segments["hidden"])
    out[index] = ~hidden
    return out


def _visible_through_lens(points: np.ndarray, valid: np.ndarray, camera: Camera, h: int, w: int, occluders: Occluders,
                          eps: float) -> np.ndarray:
    """:func:`visible` for a camera with a lens distortion: inside the image is where the lens images the
    point (its distorted pixel on the image, not beyond the model's fold: lfusd.truth.lens.project_imaged);
    the segment from the centre to the point is lens-free, cast against the whole scene."""
    from ..camera import project_imaged

    out = np.zeros(len(points), bool)
    u, v, _, imaged = project_imaged(points.astype(np.float64), camera)
    with np.errstate(invalid="ignore"):
        index = np.flatnonzero(valid & imaged & (u >= -0.5) & (u <= w - 0.5) & (v >= -0.5) & (v <= h - 0.5))
    C = camera.world_to_cam()[1]
    rays = np.empty((len(index), 6), np.float32)
    rays[:, :3] = C
    rays[:, 3:] = points[index].astype(np.float64) - C  # parameter 1 at the point, as segment_rays
    hidden = _occluded(occluders.scene, rays, eps) if len(occluders.triangles) else np.zeros(len(index), bool)
    out[index] = ~hidden
    return out


MIXED_DEPTH_REL = 0.01  # corners whose depths differ by more than this see different surfaces
MIXED_FLOW_PX = 0.5  # ... or whose forward flows differ by more than this move differently
CORNERS = ((-0.5, -0.5), (0.5, -0.5), (-0.5, 0.5), (0.5, 0.5))  # a pixel's corners, (du, dv) from its centre


def mixed_footprint(camera: Camera, h: int, w: int, here: Occluders, nxt: Occluders | None = None,
                    camera_next: Camera | None = None, parts: Parts | None = None,
                    memo: StaticMemo | None = None) -> np.ndarray:
    """(H, W) bool: the pixel's footprint holds more than one surface or motion (key ``mixed``).

    A ray through each pixel corner (u +- 1/2, v +- 1/2) is cast against the frame's rendered
    triangles (``here``), once per corner for the four pixels that share it ((H+1)(W+1) rays): a
    pixel's four corners differ when their hits differ in instance (or hit and miss), or in depth
    by more than ``MIXED_DEPTH_REL``; with the next frame's triangles (``nxt``, same triangles in
    the same order: same count) each hit is carried to t+1 on its triangle (same barycentric
    coordinates) and projected with ``camera_next``, and forward flows more than ``MIXED_FLOW_PX``
    apart differ too. The corners are the footprint's extreme points: a straight edge that crosses
    the footprint separates two of them, wherever it crosses. With ``parts`` (``here`` split by a
    neighbouring frame) each corner's first hit is the nearer of the static part's (kept in ``memo``
    between frames) and the dynamic part's (cast only where a dynamic triangle may lie before it).

    Structure that passes between the corners (a wire a tenth of a pixel wide) is found from the
    triangles: a pixel whose square a discontinuity edge (boundary, silhouette, between instances)
    crosses, not behind what its corners see, is mixed too (lfusd.truth.footprint)."""
    from ._motion_numba import mixed_pixels

    if camera.dist is not None and not camera.dist.is_identity:
        return _mixed_through_lens(camera, h, w, here, nxt, camera_next)
    _, C = camera.world_to_cam()
    n = (h + 1) * (w + 1)
    if len(here.triangles):
        t, tri, uv = _corner_hits(here, camera, camera._pixel_to_world(np.float64), np.ascontiguousarray(C, np.float64), h, w,
                                  parts, memo)
    else:
        t, tri, uv = np.full(n, np.inf, np.float32), np.zeros(n, np.uint32), np.zeros((n, 2), np.float32)
    inst = np.ascontiguousarray(here.instance if here.instance is not None else np.zeros(len(here.triangles)), np.int32)
    carry = nxt is not None and camera_next is not None and len(nxt.triangles) == len(here.triangles) and len(here.triangles) > 0
    if carry:
        Rn, Cn = camera_next.world_to_cam()
        args = (nxt.vertices, np.ascontiguousarray(nxt.triangles, np.uint32), np.asarray(camera_next.K, np.float64) @ Rn,
                np.ascontiguousarray(Cn, np.float64))
    else:
        args = (np.zeros((1, 3), np.float32), np.zeros((1, 3), np.uint32), np.eye(3), np.zeros(3))
    mixed = mixed_pixels(t, tri, uv, inst if inst.size else np.zeros(1, np.int32), carry, *args, h, w, MIXED_DEPTH_REL, MIXED_FLOW_PX)
    if len(here.triangles):
        from .footprint import crossed_by_edges

        mixed |= crossed_by_edges(here.vertices, here.triangles, inst, here.edges, camera, t, h, w, MIXED_DEPTH_REL)
    return mixed


def _mixed_through_lens(camera: Camera, h: int, w: int, here: Occluders, nxt: Occluders | None, camera_next: Camera | None) -> np.ndarray:
    """:func:`mixed_footprint` for a camera with a lens distortion: the rays the lens images at the pixel
    corners (lfusd.camera.ray_directions through ``camera.dist``), cast against the whole scene; each hit
    carried to t+1 (as the kernel does) is imaged through ``camera_next``'s lens, NaN beyond its fold."""
    from ._motion_numba import mixed_pixels
    from ..camera import project_imaged
    from ..camera import pixel_grid, ray_directions

    cu, cv = pixel_grid(h + 1, w + 1, np.float64)
    dirs = ray_directions(cu - 0.5, cv - 0.5, camera).reshape(-1, 3)  # camera-frame z = 1: the ray parameter is planar depth
    _, C = camera.world_to_cam()
    rays = np.empty((len(dirs), 6), np.float32)
    rays[:, :3], rays[:, 3:] = C, dirs
    if len(here.triangles):
        t, tri, uv = _cast(here.scene, rays)
    else:
        n = len(dirs)
        t, tri, uv = np.full(n, np.inf, np.float32), np.zeros(n, np.uint32), np.zeros((n, 2), np.float32)
    tri = np.where(np.isfinite(t), tri, 0).astype(np.uint32)
    inst = np.ascontiguousarray(here.instance if here.instance is not None else np.zeros(len(here.triangles)), np.int32)
    none = (np.zeros((1, 3), np.float32), np.zeros((1, 3), np.uint32), np.eye(3), np.zeros(3))
    mixed = mixed_pixels(t, tri, uv, inst if inst.size else np.zeros(1, np.int32), False, *none, h, w, MIXED_DEPTH_REL, MIXED_FLOW_PX)
    carry = nxt is not None and camera_next is not None and len(nxt.triangles) == len(here.triangles) and len(here.triangles) > 0
    if not carry:
        return mixed
    hit = np.isfinite(t)
    f = np.asarray(nxt.triangles, np.int64)[tri]
    vn = np.asarray(nxt.vertices, np.float64)
    b1, b2 = uv[:, :1].astype(np.float64), uv[:, 1:].astype(np.float64)
    P = vn[f[:, 0]] + b1 * (vn[f[:, 1]] - vn[f[:, 0]]) + b2 * (vn[f[:, 2]] - vn[f[:, 0]])
    pu, pv, _, imaged = project_imaged(P, camera_next)
    ok = hit & imaged
    fu = np.where(ok, pu - (cu.ravel() - 0.5), np.nan).reshape(h + 1, w + 1)
    fv = np.where(ok, pv - (cv.ravel() - 0.5), np.nan).reshape(h + 1, w + 1)
    corners = [(slice(0, h), slice(0, w)), (slice(0, h), slice(1, w + 1)), (slice(1, h + 1), slice(0, w)), (slice(1, h + 1), slice(1, w + 1))]
    with np.errstate(invalid="ignore"):
        for a in range(4):
            for b in range(a + 1, 4):
                du = fu[corners[a]] - fu[corners[b]]
                dv = fv[corners[a]] - fv[corners[b]]
                mixed |= du * du + dv * dv > MIXED_FLOW_PX * MIXED_FLOW_PX  # False where either is NaN
    return mixed


def _cast(scene, rays: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Open3D's closest hits: t (inf where none), primitive index (not to be read where t is inf), (u, v)."""
    import open3d as o3d

    hits = scene.cast_rays(o3d.core.Tensor.from_numpy(np.ascontiguousarray(rays)))
    return hits["t_hit"].numpy(), hits["primitive_ids"].numpy(), hits["primitive_uvs"].numpy()


def _corner_hits(here: Occluders, camera: Camera, A: np.ndarray, C: np.ndarray, h: int, w: int, parts: Parts | None,
                 memo: StaticMemo | None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The first hit of the ray through each pixel corner among ``here``'s triangles: t, triangle
    index (uint32), (u, v). The corner grid is the pixel grid of an (H+1) x (W+1) image shifted by
    half a pixel."""
    from ._motion_numba import corner_rays, pixel_rays

    if parts is None:
        return _cast(here.scene, pixel_rays(A, C, -0.5, -0.5, h + 1, w + 1))
    key = (parts.digest, A.tobytes(), C.tobytes(), h, w)
    held = memo.corners if memo is not None else None
    if held is not None and held["key"] == key:
        t, tri, uv = held["t"].copy(), held["tri"].copy(), held["uv"].copy()
    else:
        n = (h + 1) * (w + 1)
        if parts.static is not None:
            t, prim, uv = _cast(parts.static, pixel_rays(A, C, -0.5, -0.5, h + 1, w + 1))
            tri = np.where(np.isfinite(t), parts.static_ids[np.minimum(prim, max(len(parts.static_ids) - 1, 0))], 0).astype(np.uint32)
        else:
            t, tri, uv = np.full(n, np.inf, np.float32), np.zeros(n, np.uint32), np.zeros((n, 2), np.float32)
        if memo is not None:
            memo.corners = {"key": key, "t": t.copy(), "tri": tri.copy(), "uv": uv.copy()}
    if parts.dynamic is not None:
        # a corner ray's parameter is planar depth: the dynamic part matters only where it lies nearer
        near = np.flatnonzero(_depth_map(parts, _corner_camera(camera), h + 1, w + 1).ravel() < t)
        if len(near):
            td, prim, uvd = _cast(parts.dynamic, corner_rays(A, C, near, w + 1))
            nearer = td < t[near]  # a tie keeps the static hit
            k = near[nearer]
            t[k], tri[k], uv[k] = td[nearer], parts.dynamic_ids[prim[nearer]], uvd[nearer]
    return t, tri, uv


def _corner_camera(camera: Camera) -> Camera:
    """The camera whose pixel centres are ``camera``'s pixel corners (the corner grid as an image)."""
    K = np.array(camera.K, np.float64)
    K[0, 2] += 0.5
    K[1, 2] += 0.5
    return Camera(K, camera.cam_to_world)


# ---- stereo visibility of planar parallel rigs, from disparity alone (the KITTI export's noc masks) ----
VIS_REL = 1e-3  # relative disparity slack of the stereo visibility test (as lfusd.truth.motion.DEPTH_REL)
EDGE_REL = 0.5  # a relative disparity jump above this between neighbours is a depth edge (no slope across it)


def _one_sided_slopes(d: np.ndarray, axis: int) -> tuple[np.ndarray, np.ndarray]:
    """(towards lower index, towards higher index) differences of ``d`` along ``axis``; NaN across a
    depth edge (relative jump above EDGE_REL) or off the image."""
    a, b = (d[:, :-1], d[:, 1:]) if axis == 1 else (d[:-1], d[1:])
    g = np.where(np.abs(b - a) <= EDGE_REL * np.minimum(a, b), b - a, np.nan)
    lower, higher = np.full(d.shape, np.nan), np.full(d.shape, np.nan)
    if axis == 1:
        higher[:, :-1], lower[:, 1:] = g, g
    else:
        higher[:-1], lower[1:] = g, g
    return lower, higher


def visible_in_view(x, y, d_expected, disparity_other) -> np.ndarray:
    """Whether points seen elsewhere are visible in another view of a planar parallel rig.

    A point lands at (x, y) in the other view (sub-pixel) with disparity ``d_expected`` there
    (disparity = f_px*b/z, so depth and disparity are one test). It is visible when (x, y) lies
    inside the image and the pixel nearest (x, y) does not see a nearer surface: that pixel's
    disparity, extrapolated to (x, y) with its one-sided slopes (never across a depth edge; exact
    on planes), is the point's own (within :data:`VIS_REL`) or smaller (a surface behind the point,
    which then sits on a silhouette). A nearer surface there hides it. Decided within half a pixel of
    the other view's depth edges and creases.
    """
    D = np.nan_to_num(np.asarray(disparity_other, np.float64), nan=0.0, posinf=0.0)  # no surface: disparity 0
    h, w = D.shape
    x, y, de = (np.asarray(a, np.float64) for a in (x, y, d_expected))
    with np.errstate(invalid="ignore"):
        inside = (x >= -0.5) & (x <= w - 0.5) & (y >= -0.5) & (y <= h - 0.5) & (de > 0)
    x, y = np.where(inside, x, 0.0), np.where(inside, y, 0.0)
    xi = np.clip(np.rint(x), 0, w - 1).astype(np.int64)
    yi = np.clip(np.rint(y), 0, h - 1).astype(np.int64)
    dx, dy = x - xi, y - yi
    with np.errstate(invalid="ignore"):
        left, right = _one_sided_slopes(D, 1)
        up, down = _one_sided_slopes(D, 0)
    # the slope on the side of the point, else the other side's, else flat
    gx = np.where(dx >= 0, right[yi, xi], left[yi, xi])
    gx = np.nan_to_num(np.where(np.isnan(gx), np.where(dx >= 0, left[yi, xi], right[yi, xi]), gx))
    gy = np.where(dy >= 0, down[yi, xi], up[yi, xi])
    gy = np.nan_to_num(np.where(np.isnan(gy), np.where(dy >= 0, up[yi, xi], down[yi, xi]), gy))
    tol = VIS_REL * de
    seen = D[yi, xi] + dx * gx + dy * gy  # what the pixel's surface has at (x, y)
    return inside & (seen <= de + tol)  # the point's own surface, or one behind it


def stereo_visible(ds, frame: int, view, other, flow=None, disparity=None) -> np.ndarray:
    """(H,W) bool: which pixels of ``view`` show a point that ``other`` (same planar parallel rig)
    also sees, at ``frame``; with ``flow`` (H,W,2) and ``disparity`` (H,W), the point moved to
    view pixel (u, v) + flow with that disparity, tested against ``other`` at ``frame``."""
    d = np.asarray(ds.read(frame, view, "disparity") if disparity is None else disparity, np.float64)
    sx0, sy0 = ds.rig.offsets(tuple(view))
    sx1, sy1 = ds.rig.offsets(tuple(other))
    v, u = np.mgrid[0 : d.shape[0], 0 : d.shape[1]].astype(np.float64)
    if flow is not None:
        u, v = u + flow[..., 0], v + flow[..., 1]
    with np.errstate(invalid="ignore"):
        x, y = u - d * (sx1 - sx0), v - d * (sy1 - sy0)  # CONVENTIONS: u - d*sx, v - d*sy
    return visible_in_view(x, y, d, ds.read(frame, other, "disparity")) & np.isfinite(d)


def inside_image(x, y, width: int, height: int) -> np.ndarray:
    """Whether sub-pixel positions (x, y) fall on a pixel of a width x height image (its area,
    [-0.5, W - 0.5) x [-0.5, H - 0.5)); NaN is outside."""
    x, y = np.asarray(x, np.float64), np.asarray(y, np.float64)
    with np.errstate(invalid="ignore"):
        return (x >= -0.5) & (x < width - 0.5) & (y >= -0.5) & (y < height - 0.5)

"""What each rig sees move: motion coverage of a rig's centre view, from the stage alone.

No rendering: rays through the pixel centres of the centre view (at a small measuring
resolution, same field of view) are cast with Open3D against the stage's own triangles
(lfusd.author.geometry: the meshes Blender renders, people skinned with UsdSkel) at each frame.
A ray *sees motion* when the first surface it meets belongs to a moving object (one whose
transform or skinning is time-varying) and the point it hits moves in the image by more than
``FLOW_EPS`` pixels (at the measuring resolution) to the next frame: the point at the same
barycentric coordinates of the same triangle at t+1, projected with the camera at t+1, the
definition of ``flow_fwd`` (docs/CONVENTIONS.md); the last frame uses t-1. So the fraction of a
frame's rays that see motion is the fraction of pixels whose rendered ``|flow_fwd|`` exceeds
``FLOW_EPS`` (lfusd.truth.coverage measures that on a render).

:class:`Watch` holds the static geometry (one ray-casting scene) and every mover's triangles per
frame (one scene each, built on first use, so adding a mover costs only its own meshes): the
scene templates (lfusd.author.scenes.dynamic) ask it about candidate rigs while planning, and
:func:`rig_footage` measures every rig of a stage for ``lfusd check``. :class:`Footage` holds
one rig's result: per frame the fraction of the view that sees motion, whether a person is in
view, whether a moving object is partly hidden behind a static one, and the depth range of the
visible surfaces, which gives the rig's disparity range d = f_px * b / z.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from pxr import Usd, UsdGeom

from ..camera import Camera, RigSpec, pixel_grid, project
from .geometry import StageGeometry, triangulate
from .labels import object_table
from .vocabulary import SURFACES

# The goal of issue 16 for every rig of a generated dynamic scene.
GOAL_COVERAGE = 0.05  # moving objects cover at least this fraction of the centre view ...
GOAL_FRAMES = 0.9  # ... in at least this fraction of the frames,
GOAL_PERSON = 0.5  # and a person is in view in at least this fraction of the frames
FLOW_EPS = 0.01  # px: a surface point moving less than this in the image does not count as moving
MEASURE_WIDTH = 64  # pixels across of the measuring resolution (same field of view as the rig)
# The reference rig (RigSpec's defaults: 9x9 views, 0.125 m, 1024x1024, 39 mm lens on 36 mm): a
# preview-size stage reports what its full-size render would give.
REFERENCE = {k: getattr(RigSpec(), k) for k in ("rows", "cols", "baseline", "width", "height", "focal_length_mm", "sensor_mm")}
# Per-step disparity at the reference rig that outdoor rig placement aims its nearest surface at.
DISPARITY_GOAL = (150.0, 250.0)


def reference_spec(spec: RigSpec) -> RigSpec:
    """The reference rig at ``spec``'s pose (its spacing and layout kept)."""
    return RigSpec(**{**spec.to_dict(), **REFERENCE, "at": tuple(spec.at), "look_at": tuple(spec.look_at)})


def same_view(a: RigSpec, b: RigSpec) -> bool:
    """True when the centre views of ``a`` and ``b`` see the same field of view (lens and aspect)."""
    return (abs(a.focal_length_mm / a.sensor_mm - b.focal_length_mm / b.sensor_mm) < 1e-9
            and a.width * b.height == b.width * a.height)


@dataclass
class Footage:
    """One rig's centre view over ``frames``: ``moving`` fraction of the image that sees motion,
    ``person`` a person visible, ``occluded`` a moving object partly behind a static object (not
    a ground or water surface); ``depth`` (min, max) planar depth of every visible surface;
    ``pixels`` rays per frame."""

    rig: str
    frames: np.ndarray
    moving: np.ndarray
    person: np.ndarray
    occluded: np.ndarray
    depth: tuple[float, float]
    pixels: int
    spec: RigSpec
    reference_depth: tuple[float, float] | None = None  # depth range of the reference rig's view at the same
    # pose, when its field of view differs from the rig's (else ``depth`` is that range)

    @property
    def in_view(self) -> float:
        """Fraction of frames in which moving objects cover at least GOAL_COVERAGE of the view."""
        return float(np.mean(self.moving >= GOAL_COVERAGE)) if len(self.frames) else 0.0

    @property
    def any_motion(self) -> float:
        """Fraction of frames with any moving pixel."""
        return float(np.mean(self.moving > 0)) if len(self.frames) else 0.0

    @property
    def person_in_view(self) -> float:
        return float(np.mean(self.person)) if len(self.frames) else 0.0

    def meets_goal(self, margin: float = 0.0) -> bool:
        return self.in_view >= GOAL_FRAMES + margin and self.person_in_view >= GOAL_PERSON + margin

    def disparity(self) -> tuple[float, float, float]:
        """(min, max) disparity in px per baseline step over the visible surfaces (at the rig's own
        resolution, d = f_px * b / z), and the max over the rig's span (outermost columns)."""
        f_b = self.spec.focal_px * self.spec.baseline
        zmin, zmax = self.depth
        dmin = f_b / zmax if np.isfinite(zmax) and zmax > 0 else 0.0
        dmax = f_b / zmin if np.isfinite(zmin) and zmin > 0 else 0.0
        s = self.spec
        span = abs(s.offsets((0, s.cols - 1))[0] - s.offsets((0, 0))[0])
        return dmin, dmax, dmax * span

    def reference_disparity(self) -> tuple[float, float]:
        """(min, max) disparity in px per baseline step that the reference rig (REFERENCE: 9x9 views,
        0.125 m, 1024 px, 39 mm lens on 36 mm) would see at this rig's pose."""
        f_b = REFERENCE["focal_length_mm"] / REFERENCE["sensor_mm"] * REFERENCE["width"] * REFERENCE["baseline"]
        zmin, zmax = self.reference_depth or self.depth
        return (f_b / zmax if np.isfinite(zmax) and zmax > 0 else 0.0,
                f_b / zmin if np.isfinite(zmin) and zmin > 0 else 0.0)

    def summary(self) -> dict:
        dmin, dmax, span = self.disparity()
        rmin, rmax = self.reference_disparity()
        return {"rig": self.rig, "frames": len(self.frames), "pixels": self.pixels,
                "motion_frames": self.in_view, "any_motion_frames": self.any_motion,
                "coverage_mean": float(self.moving.mean()) if len(self.frames) else 0.0,
                "coverage_min": float(self.moving.min()) if len(self.frames) else 0.0,
                "person_frames": self.person_in_view, "occlusion_frames": float(np.mean(self.occluded)) if len(self.frames) else 0.0,
                "disparity_min_px": dmin, "disparity_max_px": dmax, "disparity_span_px": span,
                "reference_disparity_min_px": rmin, "reference_disparity_max_px": rmax}

    def line(self) -> str:
        s = self.summary()
        return (f"rig {self.rig}: moving objects >= {GOAL_COVERAGE:.0%} of the centre view in {s['motion_frames']:.0%} of "
                f"{s['frames']} frames (any motion {s['any_motion_frames']:.0%}), covering mean {s['coverage_mean']:.1%} "
                f"min {s['coverage_min']:.1%}; person in view {s['person_frames']:.0%}; occlusions {s['occlusion_frames']:.0%}; "
                f"disparity {s['disparity_min_px']:.1f}-{s['disparity_max_px']:.1f} px per step, up to "
                f"{s['disparity_span_px']:.0f} px over the rig; at the reference rig (9x9, 0.125 m, 1024 px) "
                f"{s['reference_disparity_min_px']:.1f}-{s['reference_disparity_max_px']:.1f} px per step "
                f"({s['pixels']} rays per frame)")


def measuring_spec(spec: RigSpec, width: int = MEASURE_WIDTH) -> RigSpec:
    """The rig at a measuring resolution: ``width`` pixels across (at most its own), same aspect
    and field of view, so its pixel centres sample the rig's image evenly."""
    w = min(int(width), spec.width)
    h = max(1, int(round(spec.height * w / spec.width)))
    return RigSpec(**{**spec.to_dict(), "width": w, "height": h})


@dataclass
class _Mover:
    path: str
    label: str
    gprims: list  # Usd.Prim
    rigid: list  # per gprim: (local points, triangles) or None when skinned
    cache: dict = field(default_factory=dict)  # frame -> (vertices, triangles, lo, hi)


def _time_varying(prim: Usd.Prim) -> bool:
    p = prim
    while p and not p.IsPseudoRoot():
        if p.IsA(UsdGeom.Xformable) and UsdGeom.Xformable(p).TransformMightBeTimeVarying():
            return True
        p = p.GetParent()
    return False


class Watch:
    """Ray casting of a stage's movers and static geometry at frames (see the module docstring).

    Static geometry is taken at the first frame; call :meth:`refresh` after authoring movers."""

    def __init__(self, stage: Usd.Stage, first: int | None = None, last: int | None = None):
        import open3d as o3d

        self.o3d = o3d
        self.stage = stage
        self.first = int(stage.GetStartTimeCode()) if first is None else int(first)
        self.last = int(stage.GetEndTimeCode()) if last is None else int(last)
        self.movers: dict[str, _Mover] = {}
        self._scenes = {}
        self._static = None
        self.refresh()

    def refresh(self) -> None:
        """Re-read the object table: new movers are added, removed ones dropped; the static scene
        is rebuilt only if the set of static objects changed."""
        geo = StageGeometry(self.stage)
        self.geometry = geo
        objs = object_table(self.stage)[0]
        static = []
        movers = {}
        for o in objs:
            parts = geo.parts_of(o.prim_path)
            prims = [p for p in parts if isinstance(p, Usd.Prim)]
            moving = any(geo.is_skinned(str(p.GetPath())) or _time_varying(p) for p in prims)
            if moving:
                movers[o.prim_path] = self.movers.get(o.prim_path) or self._mover(o.prim_path, o.label, prims)
            else:
                static += [(p, o.label) for p in parts]
        if set(movers) != set(self.movers):
            self._scenes: dict[int, tuple] = {}
        self._box_cache: dict[tuple, tuple] = {}
        self.movers = movers
        key = tuple(sorted(str(getattr(p, "path", None) or p.GetPath()) for p, _ in static))
        if self._static is None or self._static[0] != key:
            scene = self.o3d.t.geometry.RaycastingScene()
            solid = []
            for p, label in static:
                m = geo.mesh(p, self.first)
                if len(m.triangles):
                    scene.add_triangles(m.vertices.astype(np.float32), m.triangles.astype(np.uint32))
                    solid.append(label not in SURFACES)
            self._static = (key, scene, np.array(solid + [False], bool))
            self._static_rays: dict[bytes, tuple] = {}

    def _mover(self, path: str, label: str, prims: list) -> _Mover:
        rigid = []
        for p in prims:
            if self.geometry.is_skinned(str(p.GetPath())) or not p.IsA(UsdGeom.Mesh):
                rigid.append(None)
                continue
            m = UsdGeom.Mesh(p)
            attrs = (m.GetPointsAttr(), m.GetFaceVertexCountsAttr(), m.GetFaceVertexIndicesAttr())
            if any(a.ValueMightBeTimeVarying() for a in attrs):
                rigid.append(None)
                continue
            pts = np.array(m.GetPointsAttr().Get(Usd.TimeCode.Default()), np.float64)
            rigid.append((pts, triangulate(m.GetFaceVertexCountsAttr().Get(), m.GetFaceVertexIndicesAttr().Get())))
        return _Mover(path, label, prims, rigid)

    def _mesh(self, mv: _Mover, frame: int):
        """(vertices, triangles, lo, hi) of a mover at ``frame`` (cached)."""
        hit = mv.cache.get(frame)
        if hit is not None:
            return hit
        xf = UsdGeom.XformCache(Usd.TimeCode(frame))
        vs, ts, n = [], [], 0
        for p, rig in zip(mv.gprims, mv.rigid):
            if rig is None:
                wm = self.geometry.mesh(p, frame)
                v, t = wm.vertices, wm.triangles
            else:
                m = np.array(xf.GetLocalToWorldTransform(p), np.float64)
                v, t = self.geometry.frame.points(rig[0] @ m[:3, :3] + m[3, :3]), rig[1]
            vs.append(v)
            ts.append(t + n)
            n += len(v)
        v = np.concatenate(vs) if vs else np.zeros((0, 3))
        t = np.concatenate(ts) if ts else np.zeros((0, 3), np.int64)
        entry = (v, t, v.min(0) if len(v) else np.zeros(3), v.max(0) if len(v) else np.zeros(3))
        mv.cache[frame] = entry
        return entry

    def _boxes(self, frame: int, names: list[str]) -> tuple[np.ndarray, np.ndarray]:
        """(lo, hi), (N, 3) each: the boxes of the movers ``names`` at ``frame`` (cached per frame)."""
        key = (frame, tuple(names))
        hit = self._box_cache.get(key)
        if hit is None:
            boxes = [self._mesh(self.movers[n], frame)[2:4] for n in names]
            hit = self._box_cache[key] = (np.array([b[0] for b in boxes]), np.array([b[1] for b in boxes]))
        return hit

    def _frame_scene(self, frame: int, keep: bool):
        """(scene, mover names by geometry id) of every mover at ``frame``; kept for later calls
        when ``keep`` (Open3D allows about a thousand live scenes: measure frame by frame)."""
        hit = self._scenes.get(frame)
        if hit is not None:
            return hit
        scene = self.o3d.t.geometry.RaycastingScene()
        names = []
        for name, mv in self.movers.items():
            v, t = self._mesh(mv, frame)[:2]
            if len(t):
                scene.add_triangles(v.astype(np.float32), t.astype(np.uint32))
                names.append(name)
        entry = (scene, names)
        if keep:
            self._scenes[frame] = entry
        return entry

    def _cast(self, scene, origin: np.ndarray, dirs: np.ndarray):
        rays = np.empty((len(dirs), 6), np.float32)
        rays[:, :3] = origin
        rays[:, 3:] = dirs
        return scene.cast_rays(self.o3d.core.Tensor(rays))

    def footage(self, spec: RigSpec, frames=None, poses=None, width: int = MEASURE_WIDTH, keep: bool = True) -> Footage:
        """Measure the centre view of ``spec`` (see :meth:`footage_many`)."""
        return self.footage_many([(spec, poses)], frames, width, keep)[0]

    def footage_many(self, rigs, frames=None, width: int = MEASURE_WIDTH, keep: bool = False) -> list[Footage]:
        """Measure the centre views of ``rigs`` ((spec, poses) pairs; ``poses``: frame -> 4x4
        OpenCV cam_to_world of the centre view, or None for the spec's pose at rest) at ``frames``
        (default: every frame), at a measuring resolution ``width`` pixels across. ``keep``: keep
        the frames' ray-casting scenes for later calls (planning samples few frames)."""
        frames = np.arange(self.first, self.last + 1) if frames is None else np.asarray(list(frames), int)
        _, static, solid = self._static
        jobs = []
        for spec, poses in rigs:
            m = measuring_spec(spec, width)
            rest = spec.cam_to_world(spec.centre_view)
            u, v = pixel_grid(m.height, m.width, np.float64)
            jobs.append(dict(spec=spec, K=m.intrinsics(), u=u.ravel(), v=v.ravel(), w=m.width, h=m.height,
                             pose=(lambda f, rest=rest: rest) if poses is None else poses,
                             moving=np.zeros(len(frames)), person=np.zeros(len(frames), bool),
                             occluded=np.zeros(len(frames), bool), z=[np.inf, -np.inf]))
        for k, f in enumerate(frames):
            f = int(f)
            other = f + 1 if f < self.last else f - 1
            scene, names = self._frame_scene(f, keep)
            for job in jobs:
                K, u, v = job["K"], job["u"], job["v"]
                cam = Camera(K, job["pose"](f))
                origin = cam.cam_to_world[:3, 3]
                key = (cam.cam_to_world.tobytes(), K.tobytes())
                if key not in self._static_rays:
                    dirs = _directions(u, v, K, cam.cam_to_world)
                    r = self._cast(static, origin, dirs)
                    self._static_rays[key] = (dirs, r["t_hit"].numpy().astype(np.float64), r["geometry_ids"].numpy().astype(np.int64))
                dirs, ts, gs = self._static_rays[key]
                if names:
                    lo, hi = self._boxes(f, names)
                    visible = _any_in_frustum(lo, hi, cam, job["w"], job["h"])
                else:
                    visible = False
                if visible:
                    r = self._cast(scene, origin, dirs)
                    t = r["t_hit"].numpy().astype(np.float64)
                    g = r["geometry_ids"].numpy().astype(np.int64)
                    prim_ids, uvs = r["primitive_ids"].numpy().astype(np.int64), r["primitive_uvs"].numpy().astype(np.float64)
                else:
                    t = np.full(len(u), np.inf)
                    g = np.full(len(u), -1)
                seen = t < ts
                # a moving object behind a static object (not the ground or water) along some ray
                job["occluded"][k] = bool(np.any(np.isfinite(t) & (ts < t) & solid[np.minimum(gs, len(solid) - 1)]))
                depth = np.where(seen, t, ts)
                finite = depth[np.isfinite(depth)]
                if finite.size:
                    job["z"] = [min(job["z"][0], float(finite.min())), max(job["z"][1], float(finite.max()))]
                count = 0
                for j in np.unique(g[seen]):
                    mv = self.movers[names[j]]
                    sel = seen & (g == j)
                    job["person"][k] |= mv.label == "person"
                    now, nxt = self._mesh(mv, f), self._mesh(mv, other)
                    if len(nxt[0]) != len(now[0]):  # topology changes: every point counts as moving
                        count += int(sel.sum())
                        continue
                    tri = now[1][prim_ids[sel]]
                    a, b = uvs[sel, 0:1], uvs[sel, 1:2]
                    later = (1 - a - b) * nxt[0][tri[:, 0]] + a * nxt[0][tri[:, 1]] + b * nxt[0][tri[:, 2]]
                    pu, pv, _ = project(later, Camera(K, job["pose"](other)))
                    count += int(np.sum(np.hypot(pu - u[sel], pv - v[sel]) > FLOW_EPS))
                job["moving"][k] = count / len(u)
        return [Footage(j["spec"].name, frames, j["moving"], j["person"], j["occluded"], tuple(j["z"]), len(j["u"]), j["spec"])
                for j in jobs]


def _directions(u: np.ndarray, v: np.ndarray, K: np.ndarray, cam_to_world: np.ndarray) -> np.ndarray:
    """World directions of the rays through pixel centres (u, v), scaled to camera-frame z = 1 (the
    ray parameter is planar depth), as lfusd.camera.ray_directions, without a matrix inverse."""
    cam = np.stack([(u - K[0, 2]) / K[0, 0], (v - K[1, 2]) / K[1, 1], np.ones_like(u)], axis=-1)
    return cam @ cam_to_world[:3, :3].T


def _any_in_frustum(lo: np.ndarray, hi: np.ndarray, cam: Camera, w: int, h: int) -> bool:
    """False when every box lo[i]..hi[i] ((N, 3) each) lies wholly behind the camera or beyond one
    image border (a box across the camera plane may span the whole view)."""
    pick = np.array([[x, y, z] for x in (0, 1) for y in (0, 1) for z in (0, 1)])  # (8, 3): lo (0) or hi (1) per axis
    corners = np.where(pick[None] == 0, lo[:, None, :], hi[:, None, :])  # (N, 8, 3)
    R, C = cam.world_to_cam()
    pc = (corners - C) @ R.T
    ahead = pc[..., 2] > 1e-6
    if np.any(np.any(ahead, axis=1) & ~np.all(ahead, axis=1)):
        return True
    some = np.all(ahead, axis=1)
    if not np.any(some):
        return False
    K, pc = cam.K, pc[some]
    x = K[0, 0] * pc[..., 0] / pc[..., 2] + K[0, 2]
    y = K[1, 1] * pc[..., 1] / pc[..., 2] + K[1, 2]
    out = (x.max(1) < -0.5) | (x.min(1) > w - 0.5) | (y.max(1) < -0.5) | (y.min(1) > h - 0.5)
    return bool(np.any(~out))


def rig_footage(stage: Usd.Stage, names=None, width: int = MEASURE_WIDTH, frames=None) -> dict[str, Footage]:
    """:class:`Footage` of the centre view of every rig (or those ``names``) of ``stage``,
    following the rig's own transform at every frame."""
    from .rigs import rigs

    found = {k: v for k, v in rigs(stage).items() if names is None or k in names}
    if not found:
        return {}
    watch = Watch(stage)
    jobs = [(r.spec, lambda f, r=r: r.cam_to_world(stage, r.spec.centre_view, f)) for _, r in sorted(found.items())]
    # the reference rig's view at the same pose, where its field of view differs (depth range only)
    extra = [(reference_spec(spec), poses) for spec, poses in jobs if not same_view(spec, reference_spec(spec))]
    feet = watch.footage_many(jobs + extra, frames, width)
    out = {f.rig: f for f in feet[: len(jobs)]}
    for f in feet[len(jobs):]:
        out[f.rig].reference_depth = f.depth
    return out

"""Closed-form ray casting of moving oriented boxes: synthetic raw passes and a visibility oracle.

Independent of lfusd.truth.motion and lfusd.truth.verify: rays are intersected with boxes by the slab method,
and the raw vector pass is built from its definition in BLENDER_FACTS.md (X, Y = previous -
current, Z, W = current - next, raster pixels with y up).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np


_CORNERS = np.array([[x, y, z] for x in (-1, 1) for y in (-1, 1) for z in (-1, 1)], float)
# the 12 triangles of a box whose corner k has (x, y, z) bits (k >> 2, k >> 1 & 1, k & 1)
_FACES = np.array([[0, 1, 3], [0, 3, 2], [4, 6, 7], [4, 7, 5], [0, 4, 5], [0, 5, 1],
                   [2, 3, 7], [2, 7, 6], [0, 2, 6], [0, 6, 4], [1, 5, 7], [1, 7, 3]])


def rot(axis, deg):
    a = np.asarray(axis, float) / np.linalg.norm(axis)
    t = math.radians(deg)
    Kx = np.array([[0, -a[2], a[1]], [a[2], 0, -a[0]], [-a[1], a[0], 0]])
    return np.eye(3) + math.sin(t) * Kx + (1 - math.cos(t)) * Kx @ Kx


def pose(R=np.eye(3), t=(0, 0, 0)):
    m = np.eye(4)
    m[:3, :3], m[:3, 3] = R, t
    return m


@dataclass
class Box:
    """An oriented box: half extents and a 4x4 local-to-world pose per frame."""

    half: tuple[float, float, float]
    poses: dict[int, np.ndarray]
    instance: int = 1
    prim_path: str = "/World/Box"


@dataclass
class Scene:
    boxes: list[Box]
    K: np.ndarray
    cams: dict[int, np.ndarray]  # frame -> OpenCV cam_to_world
    H: int
    W: int
    baseline: float = 0.1
    extra: dict = field(default_factory=dict)

    def rays(self, frame):
        v, u = np.mgrid[0 : self.H, 0 : self.W].astype(float)
        pix = np.stack([u, v, np.ones_like(u)], -1)
        c2w = self.cams[frame]
        d = pix @ np.linalg.inv(self.K).T @ c2w[:3, :3].T  # camera z component 1: t = planar depth
        return np.broadcast_to(c2w[:3, 3], d.shape), d

    def cast(self, origins, dirs, frame):
        """Nearest hit parameter s (inf if none), box index (-1) and box-local hit points."""
        best = np.full(origins.shape[:-1], np.inf)
        which = np.full(origins.shape[:-1], -1)
        local = np.zeros(origins.shape)
        for k, box in enumerate(self.boxes):
            P = box.poses[frame]
            o = (origins - P[:3, 3]) @ P[:3, :3]
            d = dirs @ P[:3, :3]
            half = np.asarray(box.half)
            with np.errstate(divide="ignore", invalid="ignore"):
                t1, t2 = (-half - o) / d, (half - o) / d
            tmin = np.nanmax(np.minimum(t1, t2), axis=-1)
            tmax = np.nanmin(np.maximum(t1, t2), axis=-1)
            hit = (tmax >= tmin) & (tmin > 1e-9) & (tmin < best)
            best = np.where(hit, tmin, best)
            which = np.where(hit, k, which)
            local = np.where(hit[..., None], o + tmin[..., None] * d, local)
        return best, which, local

    def to_world(self, which, local, frame):
        out = np.full(local.shape, np.nan)
        for k, box in enumerate(self.boxes):
            sel = which == k
            P = box.poses[frame]
            out[sel] = local[sel] @ P[:3, :3].T + P[:3, 3]
        return out

    def project(self, X, frame):
        c2w = self.cams[frame]
        c = (X - c2w[:3, 3]) @ c2w[:3, :3]
        x = c @ self.K.T
        return x[..., 0] / x[..., 2], x[..., 1] / x[..., 2], c[..., 2]

    def truth(self, frame):
        """Exact per-pixel quantities at ``frame``: depth, position, instance, and the points at t+-1."""
        o, d = self.rays(frame)
        s, which, local = self.cast(o, d, frame)
        fg = which >= 0
        out = {
            "depth": np.where(fg, s, np.inf),
            "position": self.to_world(which, local, frame),
            "instance": np.where(fg, np.array([b.instance for b in self.boxes] + [0])[which], 0),
            "which": which,
        }
        for step, name in ((1, "next_position"), (-1, "prev_position")):
            if frame + step in self.cams:
                out[name] = self.to_world(which, local, frame + step)
        return out

    def raw(self, frame, exact=True):
        """Raw passes as the lead reads them from Blender's EXR (vector per BLENDER_FACTS.md)."""
        from lfusd.camera import Camera
        from lfusd.truth.motion import RawPasses

        t = self.truth(frame)
        fg = t["which"] >= 0
        v, u = np.mgrid[0 : self.H, 0 : self.W].astype(float)
        y_up = self.H - 1 - v
        vec = np.zeros((self.H, self.W, 4))
        if "prev_position" in t:
            pu, pv, _ = self.project(t["prev_position"], frame - 1)
            vec[..., 0], vec[..., 1] = pu - u, (self.H - 1 - pv) - y_up  # previous - current
        if "next_position" in t:
            nu, nv, _ = self.project(t["next_position"], frame + 1)
            vec[..., 2], vec[..., 3] = u - nu, y_up - (self.H - 1 - nv)  # current - next
        vec[~fg] = 0
        f32 = lambda a: None if a is None else np.asarray(a, np.float32)  # noqa: E731
        return RawPasses(
            depth=f32(t["depth"]),
            vector=f32(vec),
            camera=Camera(self.K.copy(), self.cams[frame].copy()),
            position=f32(t["position"]),
            instance=t["instance"].astype(np.int32),
            next_position=f32(t.get("next_position")) if exact else None,
            prev_position=f32(t.get("prev_position")) if exact else None,
        )

    def triangles(self, frame):
        """Every box's 12 triangles at ``frame`` in world space, with each triangle's instance id
        (what the render worker writes as geometry.npz)."""
        verts, tris, inst = [], [], []
        for k, b in enumerate(self.boxes):
            P = b.poses[frame]
            verts.append((_CORNERS * np.asarray(b.half)) @ P[:3, :3].T + P[:3, 3])
            tris.append(_FACES + 8 * k)
            inst.append(np.full(12, b.instance))
        return np.concatenate(verts), np.concatenate(tris), np.concatenate(inst)

    def occluders(self, frame):
        """:meth:`triangles` as lfusd.truth.visibility.Occluders."""
        from lfusd.truth.visibility import Occluders

        return Occluders(*self.triangles(frame))

    def derive(self, frame, exact=True, backend=None, memo=None):
        """lfusd.truth.motion.derive_motion of ``frame`` from this scene's raw passes, with exact
        occlusion (``memo``: a lfusd.truth.visibility.StaticMemo kept from frame to frame, as a
        derivation process keeps one per view)."""
        from lfusd.truth.motion import derive_motion

        nxt = self.raw(frame + 1, exact) if frame + 1 in self.cams else None
        prv = self.raw(frame - 1, exact) if frame - 1 in self.cams else None
        occ = {k: self.occluders(g) for k, g in (("next", frame + 1), ("prev", frame - 1), ("here", frame)) if g in self.cams}
        return derive_motion(self.raw(frame, exact), nxt, prv, baseline=self.baseline, backend=backend, occluders=occ, memo=memo)

    def visible_at(self, frame, step):
        """Oracle: is the point seen at each pixel at ``frame`` in the image and unoccluded at frame+step?"""
        t = self.truth(frame)
        fg = t["which"] >= 0
        X = t["next_position" if step > 0 else "prev_position"]
        u1, v1, z1 = self.project(X, frame + step)
        inside = (u1 >= -0.5) & (u1 <= self.W - 0.5) & (v1 >= -0.5) & (v1 <= self.H - 0.5) & (z1 > 0)
        C = self.cams[frame + step][:3, 3]
        d = np.where(fg[..., None], X - C, 1.0)
        s, _, _ = self.cast(np.broadcast_to(C, d.shape), d, frame + step)
        return fg & inside & (s >= 1 - 1e-6)


def intrinsics(f, W, H):
    return np.array([[f, 0, (W - 1) / 2], [0, f, (H - 1) / 2], [0, 0, 1.0]])

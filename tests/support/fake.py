"""An in-memory stand-in for ``lfusd.Dataset`` built from closed-form geometry.

Scene (in the rig frame = the centre camera's OpenCV frame): a static textured wall at z = ZB and
a textured square of half-size S at z = ZF(t) that moves by V per frame. Every view of the planar
parallel rig is rendered by ray-plane intersection at pixel centres, so a point at disparity d
seen at (u, v) in the centre view appears at (u - d*sx, v - d*sy) in view (r, c) exactly as
CONVENTIONS.md states. All ground-truth keys are the closed-form values.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from lfusd.camera import RigSpec

ZB = 3.0
ZF0 = 1.6
S = 0.35
V = np.array([0.03, -0.02, -0.04])  # metres per frame, rig frame


def texture(x: np.ndarray, y: np.ndarray, seed: int) -> np.ndarray:
    """A smooth, aperiodic-looking colour texture on plane coordinates (metres), values in [0, 1]."""
    rng = np.random.default_rng(seed)
    out = np.zeros(x.shape + (3,))
    for c in range(3):
        acc = np.zeros(x.shape)
        for _ in range(6):
            k = rng.uniform(8, 30)
            a = rng.uniform(0, np.pi)
            ph = rng.uniform(0, 2 * np.pi)
            acc += np.sin(k * (np.cos(a) * x + np.sin(a) * y) + ph)
        out[..., c] = 0.5 + 0.07 * acc
    return np.clip(out, 0.02, 0.98)


@dataclass
class FakeObject:
    prim_path: str
    label: str
    poses: dict = field(default_factory=dict)


class FakeDataset:
    """Same attributes as lfusd.Dataset, computed analytically."""

    def __init__(self, root: Path | str = "/nonexistent/fake", rows: int = 5, cols: int = 5, width: int = 48, height: int = 40, frames=(1, 2, 3), baseline: float = 0.05):
        self.root = Path(root)
        self.rig = RigSpec(rows=rows, cols=cols, baseline=baseline, focal_length_mm=36.0, sensor_mm=36.0, width=width, height=height)
        self.frames = list(frames)
        self.views = self.rig.views
        self.baseline = baseline
        self.classes = ["unlabelled", "wall", "box"]
        t0 = self.frames[0]
        poses = {}
        for t in self.frames:
            p = np.eye(4)
            p[:3, 3] = self.rig.rig_to_world()[:3, :3] @ self._fg_centre(t) + self.rig.rig_to_world()[:3, 3]
            poses[t] = p
        self.objects = {1: FakeObject("/World/Wall", "wall", {t: np.eye(4) for t in self.frames}), 2: FakeObject("/World/Box", "box", poses)}
        self._t0 = t0
        self._cache: dict = {}

    # -- geometry --------------------------------------------------------------------------------
    def _fg_centre(self, t: float) -> np.ndarray:
        return np.array([0.0, 0.0, ZF0]) + (t - self.frames[0]) * V

    def intrinsics(self, view) -> np.ndarray:
        return self.rig.intrinsics()

    def cam_to_world(self, frame, view) -> np.ndarray:
        return self.rig.cam_to_world(view)

    def _rays(self, view):
        k = self.rig.intrinsics()
        f, cx, cy = k[0, 0], k[0, 2], k[1, 2]
        v, u = np.mgrid[0 : self.rig.height, 0 : self.rig.width].astype(np.float64)
        sx, sy = self.rig.offsets(view)
        origin = np.array([sx * self.baseline, sy * self.baseline, 0.0])
        return origin, (u - cx) / f, (v - cy) / f

    def _surface(self, t: float, view):
        """Per pixel: rig-frame point, plane id (1 wall, 2 box), texture coords."""
        o, dx, dy = self._rays(view)
        c = self._fg_centre(t)
        xf, yf = o[0] + dx * c[2], o[1] + dy * c[2]
        fg = (np.abs(xf - c[0]) <= S) & (np.abs(yf - c[1]) <= S)
        xb, yb = o[0] + dx * ZB, o[1] + dy * ZB
        pts = np.where(fg[..., None], np.stack([xf, yf, np.full_like(xf, c[2])], -1), np.stack([xb, yb, np.full_like(xb, ZB)], -1))
        return pts, np.where(fg, 2, 1), fg

    def _project(self, p_rig: np.ndarray, view):
        k = self.rig.intrinsics()
        sx, sy = self.rig.offsets(view)
        q = p_rig - np.array([sx * self.baseline, sy * self.baseline, 0.0])
        return k[0, 0] * q[..., 0] / q[..., 2] + k[0, 2], k[1, 1] * q[..., 1] / q[..., 2] + k[1, 2], q[..., 2]

    def _compute(self, t, view, key):
        pts, ids, fg = self._surface(t, view)
        f = self.rig.focal_px
        r2w = self.rig.rig_to_world()
        if key == "rgb":
            c = self._fg_centre(t)
            col = np.where(fg[..., None], texture(pts[..., 0] - c[0], pts[..., 1] - c[1], 2), texture(pts[..., 0], pts[..., 1], 1))
            return np.round(col * 255).astype(np.uint8)
        if key == "depth":
            return pts[..., 2].astype(np.float32)
        if key == "disparity":
            return (f * self.baseline / pts[..., 2]).astype(np.float32)
        if key == "position":
            return (pts @ r2w[:3, :3].T + r2w[:3, 3]).astype(np.float32)
        if key == "normal":
            return np.broadcast_to(r2w[:3, :3] @ np.array([0.0, 0.0, -1.0]), pts.shape).astype(np.float32).copy()
        if key in ("instance", "semantic"):
            return ids.astype(np.int32)
        from lfusd.keys import KEYS

        if key in KEYS and KEYS[key].effect is not None:  # rendered without camera effects, like a dataset without them
            raise KeyError(key)
        step = 1 if key.endswith("fwd") or key in ("scene_flow", "disparity_change") else -1
        defined = (t + step) in self.frames
        vel = np.where(fg[..., None], step * V, 0.0)
        if key in ("valid_fwd", "valid_bwd"):
            return np.full(ids.shape, defined)
        if not defined and not key.startswith("occlusion"):
            nan_shape = {"flow_fwd": ids.shape + (2,), "flow_bwd": ids.shape + (2,), "scene_flow": ids.shape + (3,)}.get(key, ids.shape)
            return np.full(nan_shape, np.nan, np.float32)
        moved = pts + vel
        u1, v1, z1 = self._project(moved, view)
        v0, u0 = np.mgrid[0 : self.rig.height, 0 : self.rig.width].astype(np.float64)
        if key in ("flow_fwd", "flow_bwd"):
            return np.stack([u1 - u0, v1 - v0], -1).astype(np.float32)
        if key == "scene_flow":
            return (vel @ r2w[:3, :3].T).astype(np.float32)
        if key == "disparity_change":
            return (f * self.baseline / z1 - f * self.baseline / pts[..., 2]).astype(np.float32)
        if key in ("occlusion_fwd", "occlusion_bwd"):
            if not defined:
                return np.zeros(ids.shape, bool)
            inside = (u1 >= -0.5) & (u1 <= self.rig.width - 0.5) & (v1 >= -0.5) & (v1 <= self.rig.height - 0.5)
            # hidden: a wall point whose ray at t+step meets the box first
            c1 = self._fg_centre(t + step)
            o, _, _ = self._rays(view)
            d = moved - o
            xf, yf = o[0] + d[..., 0] / d[..., 2] * c1[2], o[1] + d[..., 1] / d[..., 2] * c1[2]
            hidden = ~fg & (np.abs(xf - c1[0]) <= S) & (np.abs(yf - c1[1]) <= S)
            return ~inside | hidden
        raise KeyError(key)

    def read(self, frame, view, key):
        from lfusd import LfusdError

        if frame not in self.frames:
            raise LfusdError(f"frame {frame} is not in the dataset")
        if tuple(view) not in self.views:
            raise LfusdError(f"view {view} is not in the dataset")
        ck = (frame, tuple(view), key)
        if ck not in self._cache:
            self._cache[ck] = self._compute(frame, tuple(view), key)
        return self._cache[ck].copy()


def fake_run_units(rendered: list | None = None):
    """A stand-in for ``lfusd.render.executors.run_units``: every view of every unit gets files
    holding no image and a matching completion record, as a worker's commit would; each
    (frame, view key) goes into ``rendered`` when given."""
    from lfusd.data import integrity
    from lfusd.layout import frame_dir

    def run_units(units, req, report):
        for u in units:
            for f in u.frames:
                for key in u.cameras:
                    d = frame_dir(req.out, u.rig, f) / key
                    d.mkdir(parents=True, exist_ok=True)
                    for name in integrity.RENDER_FILES:
                        (d / name).write_bytes(b"fake")
                    integrity.record_render(d)
                    if rendered is not None:
                        rendered.append((f, key))
        return "cpu"

    return run_units

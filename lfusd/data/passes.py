"""Raw render passes (Blender's EXRs) and the derived static keys computed from them, in NumPy.

Raw files per view (written by the renderer):
- ``rgb.exr``: linear RGB (half float), the beauty render;
- ``passes.exr``: Blender's multilayer EXR of the exact data render (1 sample at each pixel
  centre): the passes of :data:`lfusd.keys.RAW_PASSES` (Depth.Z, Normal.XYZ, Position.XYZ,
  Vector.XYZW, Object Index.X, and with render-video the AOVs next_position / prev_position). Format version 2 keeps it only with
  ``--keep-raw``: its keys go to gt.exr and motion.exr (lfusd.data.store).

Everything here follows docs/CONVENTIONS.md; Blender's own conventions are converted in
this one place (background depth 1e10 -> inf; object index float -> int32 instance id). The
derived static keys of lfusd.keys are computed by the functions in :data:`DERIVED`.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Callable

import numpy as np
import OpenEXR

from ..camera import Camera, backproject, pixel_grid, ray_lengths
from ..errors import LfusdError
from ..keys import BACKGROUND_DEPTH, MOTION_AOVS, RAW_PASS, RAW_PASSES


def read_exr(path: str | Path) -> dict[str, np.ndarray]:
    """Every channel of an EXR (all parts), by channel name, rows top to bottom."""
    try:
        f = OpenEXR.File(str(path))
    except Exception as e:  # OpenEXR raises plain exceptions for missing or corrupt files
        raise LfusdError(f"cannot read EXR {path} ({e}); re-render this view") from None
    out: dict[str, np.ndarray] = {}
    for part in f.parts:
        for name, ch in part.channels.items():
            out[name] = ch.pixels
    return out


def _channel(channels: dict[str, np.ndarray], suffix: str, path) -> np.ndarray:
    for name, arr in channels.items():
        if name == suffix or name.endswith("." + suffix):
            return arr
    raise LfusdError(f"{path} has no {suffix} channel; re-render this view")


def read_raw(path: str | Path) -> dict[str, np.ndarray]:
    """The data passes of one view (:data:`lfusd.keys.RAW_PASSES`), converted to the conventions:
    depth, normal, position, instance, and ``vector`` (Blender's raw (H,W,4) vector pass, see
    lfusd.truth.motion) and the motion AOVs where the file has them."""
    ch = read_exr(path)

    def read(p) -> np.ndarray:
        a = np.stack([_channel(ch, c, path) for c in p.channel_names], axis=-1) if len(p.channels) > 1 else _channel(ch, p.channel_names[0], path)
        return a if p.key == "instance" else a.astype(p.dtype)

    depth = read(RAW_PASS["depth"])
    surface = depth < BACKGROUND_DEPTH
    depth = np.where(surface, depth, np.float32(np.inf))
    nan = np.float32(np.nan)
    raw = {"depth": depth}
    for p in RAW_PASSES:
        if p.key == "depth" or p.neighbour:
            continue
        if not p.required and not any(n.endswith("." + p.channel_names[0]) or n == p.channel_names[0] for n in ch):
            continue  # the vector pass: Dataset.raw_passes names its absence
        if p.key == "instance":  # Blender stores the pass index as a float
            instance = np.rint(read(p)).astype(p.dtype)
            instance[~surface] = 0
            raw[p.key] = instance
        elif p.key == "vector":
            raw[p.key] = read(p)
        else:
            raw[p.key] = np.where(surface[..., None], read(p), nan)
    for p in MOTION_AOVS:  # present when rendered by render-video; (H,W,4) RGBA groups
        arr = next((a for n, a in ch.items() if n.endswith("." + p.layer)), None)
        if arr is not None:
            raw[p.key] = np.where(surface[..., None], arr[..., : len(p.channels)].astype(p.dtype), nan)
    return raw


def read_rgb_linear(path: str | Path) -> np.ndarray:
    """Linear RGB float32 (H,W,3) of the beauty render."""
    ch = read_exr(path)
    if "RGB" in ch:  # OpenEXR's Python API groups R, G, B into one (H,W,3) array
        return ch["RGB"].astype(np.float32)
    return np.stack([_channel(ch, c, path) for c in "RGB"], axis=-1).astype(np.float32)


def linear_to_srgb8(rgb: np.ndarray) -> np.ndarray:
    """Linear RGB -> 8-bit sRGB (IEC 61966-2-1 transfer function, clipped, rounded)."""
    x = np.clip(rgb, 0.0, 1.0)
    s = np.where(x <= 0.0031308, 12.92 * x, 1.055 * np.power(x, 1 / 2.4) - 0.055)
    return np.rint(s * 255.0).astype(np.uint8)


def disparity(depth: np.ndarray, focal_px: float, baseline: float) -> np.ndarray:
    """d = f_px * b / z in pixels per baseline step; 0 where there is no surface."""
    with np.errstate(divide="ignore"):
        d = np.float32(focal_px * baseline) / depth
    return np.where(np.isfinite(depth), d, np.float32(0.0)).astype(np.float32)


def semantic(instance: np.ndarray, class_of_instance: np.ndarray) -> np.ndarray:
    """Class id per pixel from the instance ids (``class_of_instance[id]``, 0 = background)."""
    return class_of_instance[instance].astype(np.int32)


def depth_euclidean(depth: np.ndarray, K: np.ndarray) -> np.ndarray:
    """Distance from the camera centre along each pixel's ray, depth * ||K^-1 [u, v, 1]||; inf where depth is."""
    h, w = depth.shape
    return (depth * ray_lengths(K, h, w)).astype(np.float32)


def position(depth: np.ndarray, K: np.ndarray, cam_to_world: np.ndarray) -> np.ndarray:
    """World position of the surface at each pixel centre from planar depth and the pose (float64
    arithmetic, float32 result); NaN where there is no surface."""
    h, w = depth.shape
    u, v = pixel_grid(h, w, np.float64)
    fg = np.isfinite(depth)
    p = backproject(u, v, np.where(fg, depth, 0).astype(np.float64), Camera(np.asarray(K, np.float64), np.asarray(cam_to_world, np.float64)))
    return np.where(fg[..., None], p, np.nan).astype(np.float32)


@dataclass(frozen=True)
class ViewInfo:
    """What a derived static key needs beside the stored keys: the view's K and pose, the rig baseline, the class table."""

    K: np.ndarray
    baseline: float
    class_of_instance: np.ndarray
    cam_to_world: np.ndarray | None = None


# Derived static keys (lfusd.keys.STATIC): name -> f(stored keys {depth, instance, ...}, ViewInfo).
DERIVED: dict[str, Callable[[dict, ViewInfo], np.ndarray]] = {
    "position": lambda raw, info: position(raw["depth"], info.K, info.cam_to_world),
    "semantic": lambda raw, info: semantic(raw["instance"], info.class_of_instance),
    "disparity": lambda raw, info: disparity(raw["depth"], float(info.K[0, 0]), info.baseline),
    "depth_euclidean": lambda raw, info: depth_euclidean(raw["depth"], info.K),
}


@dataclass
class RawPasses:
    """The raw passes of one view at one frame (see docs/CONVENTIONS.md and docs/blender-facts.md).

    depth (H,W) planar z in metres, inf (or >= 1e9) on background; vector (H,W,4) Blender's raw
    vector pass; position (H,W,3) world position; instance (H,W) int, 0 = background;
    next_position / prev_position (H,W,3) world position at t+1 / t-1 of the point seen at t,
    NaN where unknown. Only depth, vector and camera are required.
    """

    depth: np.ndarray
    vector: np.ndarray
    camera: Camera
    position: np.ndarray | None = None
    instance: np.ndarray | None = None
    next_position: np.ndarray | None = None
    prev_position: np.ndarray | None = None

    @property
    def shape(self) -> tuple[int, int]:
        return tuple(self.depth.shape[:2])

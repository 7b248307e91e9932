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

import os
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Callable

import numpy as np
import OpenEXR

from ..camera import FOLD_TOL_PX, Camera, Distortion, backproject, pixel_grid, ray_lengths, undistort_pixels
from ..errors import LfusdError
from ..keys import BACKGROUND_DEPTH, MATERIAL_AOV, MATERIAL_MASKS, MOTION_AOVS, RAW_PASS, RAW_PASSES


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


_PIXEL_BYTES = {0: 4, 1: 2, 2: 4}  # OpenEXR pixel types: UINT, HALF, FLOAT


def _exr_header(head: bytes, pos: int) -> tuple[dict[str, bytes], int]:
    """The attributes of one EXR header starting at ``pos`` (name -> raw value), and where it ends."""
    import struct

    attrs = {}
    while head[pos] != 0:
        name_end = head.index(b"\0", pos)
        type_end = head.index(b"\0", name_end + 1)
        (n,) = struct.unpack_from("<i", head, type_end + 1)
        attrs[head[pos:name_end].decode()] = head[type_end + 5 : type_end + 5 + n]
        pos = type_end + 5 + n
    return attrs, pos + 1


@dataclass(frozen=True)
class _Part:
    """One part of an uncompressed scanline EXR: its channels (name, OpenEXR pixel type) in file
    order, size, the bytes of a line chunk's header and pixels, and its line offset table."""

    channels: tuple[tuple[str, int], ...]
    shape: tuple[int, int]
    y0: int
    head: int
    line: int
    offsets: np.ndarray


def _exr_headers(path: str | Path) -> tuple[list[dict[str, bytes]], int, int, int] | None:
    """An EXR's headers (one per part: attribute name -> raw value), where they end, its version
    flags and the file's size; None for a file that is not an EXR. Raises what a damaged header
    raises (the callers catch it)."""
    import struct

    with open(path, "rb") as f:
        head = f.read(1 << 20)
        size = os.fstat(f.fileno()).st_size
    flags = struct.unpack_from("<i", head, 4)[0] if len(head) >= 8 else 0
    if head[:4] != b"\x76\x2f\x31\x01" or flags & 0xFF != 2:
        return None
    multi = bool(flags & 0x1000)
    headers, pos = [], 8
    while True:
        attrs, pos = _exr_header(head, pos)
        headers.append(attrs)
        if not multi or head[pos] == 0:
            return headers, pos + multi, flags, size  # + the empty header that ends a multi-part file's list


def _uncompressed_parts(path: str | Path) -> list[_Part] | None:
    """The parts of an uncompressed scanline EXR whose every line is in the file (see
    :func:`uncompressed_channels`); None for any other EXR; LfusdError for one cut off or longer."""
    import struct

    try:
        found = _exr_headers(path)
        if found is None or found[2] & 0xA00:
            return None  # not an EXR, tiled or deep: decode it
        headers, pos, flags, size = found
        multi = bool(flags & 0x1000)
        parts = []
        for attrs in headers:
            if attrs.get("compression") != b"\x00" or (multi and attrs.get("type") != b"scanlineimage"):
                return None
            x0, y0, x1, y1 = struct.unpack("<4i", attrs["dataWindow"])
            h, w = y1 - y0 + 1, x1 - x0 + 1
            line, chl, i, channels = 0, attrs["channels"], 0, []
            while chl[i] != 0:
                end = chl.index(b"\0", i)
                ptype, _, xs, ys = struct.unpack_from("<iB3xii", chl, end + 1)
                if (xs, ys) != (1, 1) or ptype not in _PIXEL_BYTES:
                    return None
                channels.append((chl[i:end].decode(), ptype))
                line += w * _PIXEL_BYTES[ptype]
                i = end + 17
            parts.append(_Part(tuple(channels), (h, w), y0, 12 if multi else 8, line, np.zeros(0, "<u8")))
        with open(path, "rb") as f:
            f.seek(pos)
            # uncompressed: one line per chunk
            parts = [replace(p, offsets=np.frombuffer(f.read(8 * p.shape[0]), "<u8")) for p in parts]
    except (OSError, ValueError, KeyError, IndexError, struct.error, UnicodeDecodeError):
        return None  # unreadable or a header this parser does not know: decoding it decides
    data = pos + 8 * sum(p.shape[0] for p in parts)
    offsets = np.concatenate([p.offsets for p in parts]) if parts else np.zeros(0, "<u8")
    lengths = np.concatenate([np.full(p.shape[0], p.head + p.line, np.uint64) for p in parts]) if parts else offsets
    order = np.argsort(offsets, kind="stable")
    start, length = offsets[order], lengths[order]
    whole = offsets.size == sum(p.shape[0] for p in parts) and offsets.size > 0 and int(start[0]) == data
    whole = whole and np.array_equal(start[1:], start[:-1] + length[:-1]) and int(start[-1] + length[-1]) == size
    if not whole:
        need = data + sum(p.shape[0] * (p.head + p.line) for p in parts)
        raise LfusdError(f"cannot read EXR {path} (it holds {size} bytes where its headers need {need}); re-render this view")
    return parts


# OpenEXR's scanlines per chunk by compression (NONE, RLE, ZIPS, ZIP, PIZ, PXR24, B44, B44A, DWAA, DWAB)
_LINES_PER_CHUNK = {0: 1, 1: 1, 2: 1, 3: 16, 4: 32, 5: 16, 6: 32, 7: 32, 8: 32, 9: 256}


def chunks_start(path: str | Path) -> int | None:
    """Where the chunks of a scanline EXR begin: the end of its headers and chunk offset tables.

    The bytes before depend on the header (Blender stamps the date and render time into it, and the
    tables hold absolute offsets); the bytes from here on are the chunks alone, the same for the
    same pixels written the same way. None for an EXR this parser does not know (tiled single-part,
    a compression it has no table for, unreadable)."""
    import struct

    try:
        found = _exr_headers(path)
        if found is None or found[2] & 0x800:
            return None  # not an EXR, or deep data
        headers, pos, flags, size = found
        chunks = 0
        for attrs in headers:
            if "chunkCount" in attrs:  # required in every part of a multi-part file
                chunks += struct.unpack("<i", attrs["chunkCount"])[0]
            elif flags & 0x200 or attrs.get("compression", b"\xff")[0] not in _LINES_PER_CHUNK:
                return None  # tiled, or an unknown compression
            else:
                _, y0, _, y1 = struct.unpack("<4i", attrs["dataWindow"])
                chunks += -(-(y1 - y0 + 1) // _LINES_PER_CHUNK[attrs["compression"][0]])
    except (OSError, ValueError, KeyError, IndexError, struct.error, UnicodeDecodeError):
        return None
    start = pos + 8 * chunks
    return start if start <= size else None


def uncompressed_channels(path: str | Path) -> tuple[list[str], tuple[int, int]] | None:
    """(channel names, (H, W)) of an uncompressed scanline EXR (single-part, as the render worker has Blender write
    its multilayer files, or multi-part) whose every scanline is in the file, checked without decoding: the
    line offset tables must put each line, of the size its part's channels give, one after the
    other up to the file's last byte. None for any other EXR (decode it to check it); LfusdError
    for an uncompressed file that is cut off or longer (OpenEXR's decoder only warns about a cut-off
    uncompressed file). The Blender worker writes transient raw passes this way
    (lfusd.render.request.raw_codec); this check reads the headers and the offset tables alone."""
    parts = _uncompressed_parts(path)
    if parts is None:
        return None
    shapes = {p.shape for p in parts}
    return [name for p in parts for name, _ in p.channels], shapes.pop() if len(shapes) == 1 else (0, 0)


_DTYPES = {0: "<u4", 1: "<f2", 2: "<f4"}  # OpenEXR pixel types: UINT, HALF, FLOAT
_GROUPS = ("RGBA", "RGB")  # the colour groups OpenEXR's Python API returns as one (H, W, n) array


def read_uncompressed(path: str | Path, layers=None) -> dict[str, np.ndarray] | None:
    """Every channel of an uncompressed scanline EXR as :func:`read_exr` returns it (colour groups
    as one array), or only those of the parts holding a channel of ``layers`` (pass names such as
    ``Depth``: in a file of a part per pass, Blender's Combined is not read); None for any other EXR (decode it with
    :func:`read_exr`); LfusdError for a file cut off or longer (:func:`uncompressed_channels`).

    The arrays are read-only views into each part's lines, mapped from the file: no decoding, no copy per
    channel. Each line's chunk header must name its line and size, else the file is left to
    OpenEXR's decoder."""
    parts = _uncompressed_parts(path)
    if parts is None:
        return None
    import mmap

    out: dict[str, np.ndarray] = {}
    with open(path, "rb") as f:
        size = os.fstat(f.fileno()).st_size
        # mapped, not read: the page cache's own pages, without a copy (a third of the read's CPU);
        # the arrays keep the mapping alive, and the file stays readable through it if it is removed
        try:
            m = mmap.mmap(f.fileno(), 0, access=mmap.ACCESS_READ) if size else None
        except (OSError, ValueError):
            return None  # a file system that cannot map files: OpenEXR's decoder reads it
        for p in parts:
            if layers is not None and not any(_layer(name) in layers for name, _ in p.channels):
                continue
            (h, w), chunk = p.shape, p.head + p.line
            start = int(p.offsets[0])
            if not np.array_equal(p.offsets, start + chunk * np.arange(h, dtype=np.uint64)):
                return None  # lines not in order in the file
            if m is None or start + h * chunk > size:
                raise LfusdError(f"cannot read EXR {path} (it was cut off while being read); re-render this view")
            rows = np.frombuffer(m, np.uint8, h * chunk, start).reshape(h, chunk)  # read-only
            fields = rows[:, : p.head].view("<i4")  # a line chunk's header: (part number,) y, pixel bytes
            if not (np.array_equal(fields[:, -2], p.y0 + np.arange(h)) and (fields[:, -1] == p.line).all()):
                return None
            at, pos = {}, p.head
            for name, ptype in p.channels:
                at[name] = (pos, ptype)
                out[name] = rows[:, pos : pos + w * _PIXEL_BYTES[ptype]].view(_DTYPES[ptype])
                pos += w * _PIXEL_BYTES[ptype]
            _group_colours(out, at, rows, w)
    return out


def _layer(channel: str) -> str:
    """The pass of a multilayer EXR channel: ``Depth`` of ``ViewLayer.Depth.Z``, ``next_position`` of ``ViewLayer.next_position.R``."""
    parts = channel.split(".")
    return parts[-2] if len(parts) > 1 else parts[0]


def _group_colours(out: dict[str, np.ndarray], at: dict[str, tuple[int, int]], rows: np.ndarray, w: int) -> None:
    """Replace the R, G, B(, A) channels of one prefix in ``out`` by one (H, W, n) view, as OpenEXR's
    Python API groups them. The file holds a part's channels in name order (A, B, G, R), one after
    the other in each line: the group is those bytes seen as (H, n, W), its channel axis reversed."""
    prefixes: dict[str, set[str]] = {}
    for name in at:
        prefix, _, comp = name.rpartition(".")
        prefixes.setdefault(prefix, set()).add(comp)
    for prefix, comps in prefixes.items():
        group = next((g for g in _GROUPS if comps == set(g)), None)
        if group is None or not prefix:
            continue
        names = [f"{prefix}.{c}" for c in sorted(group)]
        (pos, ptype), size = at[names[0]], _PIXEL_BYTES[at[names[0]][1]]
        if any(at[n] != (pos + k * w * size, ptype) for k, n in enumerate(names)):
            continue  # not side by side: left as single channels (read_raw then falls back to decoding)
        block = rows[:, pos : pos + len(names) * w * size].view(_DTYPES[ptype]).reshape(rows.shape[0], len(names), w)
        out[prefix] = block[:, ::-1, :].transpose(0, 2, 1)  # R, G, B(, A): name order reversed
        for n in names:
            del out[n]


def _find(channels: dict[str, np.ndarray], suffix: str) -> np.ndarray | None:
    """The channel named ``suffix``, with or without its view layer's prefix; None if absent."""
    return next((arr for name, arr in channels.items() if name == suffix or name.endswith("." + suffix)), None)


def _channel(channels: dict[str, np.ndarray], suffix: str, path) -> np.ndarray:
    arr = _find(channels, suffix)
    if arr is None:
        raise LfusdError(f"{path} has no {suffix} channel; re-render this view")
    return arr


_RAW_LAYERS = frozenset(p.layer for p in RAW_PASSES)


def read_raw(path: str | Path) -> dict[str, np.ndarray]:
    """The data passes of one view (:data:`lfusd.keys.RAW_PASSES`), converted to the conventions:
    depth, normal, position, instance, and ``vector`` (Blender's raw (H,W,4) vector pass, see
    lfusd.truth.motion) and the motion AOVs where the file has them."""
    # transient raw passes are uncompressed: read as views of their lines (lfusd.render.request.raw_codec)
    ch = read_uncompressed(path, _RAW_LAYERS)
    if ch is None:
        ch = read_exr(path)
    # Each key is built once from the contract (lfusd.keys.RAW_PASSES) and masked in place (no
    # np.where copies: a third of the time at 1024x1024).
    def read(p) -> np.ndarray:
        if len(p.channels) > 1:
            return np.stack([_channel(ch, c, path) for c in p.channel_names], axis=-1).astype(p.dtype, copy=False)
        return np.array(_channel(ch, p.channel_names[0], path), p.dtype, order="C")

    depth = read(RAW_PASS["depth"])
    background = ~(depth < BACKGROUND_DEPTH)
    depth[background] = np.inf
    raw = {"depth": depth}
    for p in RAW_PASSES:
        if p.key == "depth" or p.aov:
            continue
        if not p.required and _find(ch, p.channel_names[0]) is None:
            continue  # the vector pass: Dataset.raw_passes names its absence
        if p.key == "instance":  # Blender stores the pass index as a float
            instance = np.rint(_channel(ch, p.channel_names[0], path)).astype(p.dtype)
            instance[background] = 0
            raw[p.key] = instance
        elif p.key == "vector":
            raw[p.key] = read(p)
        else:
            raw[p.key] = a = read(p)
            a[background] = np.nan
    for p in MOTION_AOVS:  # present when rendered by render-video; (H,W,4) RGBA groups
        arr = next((a for n, a in ch.items() if n.endswith("." + p.layer)), None)
        if arr is not None:
            raw[p.key] = a = np.array(arr[..., : len(p.channels)], p.dtype, order="C")
            a[background] = np.nan
    arr = next((a for n, a in ch.items() if n.endswith("." + MATERIAL_AOV.layer)), None)
    if arr is not None:  # --materials: the flags of lfusd.keys.MATERIAL_MASKS, a small integer as a float in R
        flags = np.rint(arr[..., 0]).astype(np.int32)
        flags[background] = 0
        raw["material"] = flags
        for key, bit in MATERIAL_MASKS.items():
            raw[key] = (flags & bit) != 0
    return raw


def read_rgb(path: str | Path) -> np.ndarray:
    """Linear RGB (H,W,3) of the beauty render, as stored (half float for lfusd's renders)."""
    ch = read_exr(path)
    if "RGB" in ch:  # OpenEXR's Python API groups R, G, B into one (H,W,3) array
        return ch["RGB"]
    return np.stack([_channel(ch, c, path) for c in "RGB"], axis=-1)


def read_rgb_linear(path: str | Path) -> np.ndarray:
    """Linear RGB float32 (H,W,3) of the beauty render."""
    return read_rgb(path).astype(np.float32)


_SRGB8_OF_HALF: list[np.ndarray] = []


def linear_to_srgb8(rgb: np.ndarray) -> np.ndarray:
    """Linear RGB -> 8-bit sRGB (IEC 61966-2-1 transfer function, clipped, rounded). Half-float input
    is looked up in a table of this function's value for every half (the same numbers as converting it
    to float32 first, in a tenth of the time)."""
    if np.asarray(rgb).dtype == np.float16:
        if not _SRGB8_OF_HALF:
            with np.errstate(invalid="ignore"):  # the table holds the NaN halves too
                _SRGB8_OF_HALF.append(linear_to_srgb8(np.arange(1 << 16, dtype=np.uint16).view(np.float16).astype(np.float32)))
        return _SRGB8_OF_HALF[0][np.asarray(rgb).view(np.uint16)]
    x = np.clip(rgb, 0.0, 1.0)
    s = np.where(x <= 0.0031308, 12.92 * x, 1.055 * np.power(x, 1 / 2.4) - 0.055)
    return np.rint(s * 255.0).astype(np.uint8)


def disparity(depth: np.ndarray, focal_px: float, baseline: float) -> np.ndarray:
    """d = f_px * b / z in pixels per baseline step; 0 where there is no surface."""
    with np.errstate(divide="ignore"):
        d = np.float32(focal_px * baseline) / depth
    return np.where(np.isfinite(depth), d, np.float32(0.0)).astype(np.float32)


def disparity_distorted(depth: np.ndarray, K: np.ndarray, dist: Distortion, baseline: float) -> np.ndarray:
    """``disparity`` of a view with a lens distortion (docs/CONVENTIONS.md, "Lens distortion"): d = u - u',
    u' the distorted column at which the view's camera moved one baseline along its x axis (same K, same
    lens) images the pixel's surface point; f_px * b / z without distortion. 0 where no surface; NaN where
    the lens does not image the point there (beyond its fold: no distorted pixel sees it)."""
    h, w = depth.shape
    K = np.asarray(K, np.float64)
    u, v = pixel_grid(h, w, np.float64)
    uu, vu = undistort_pixels(u, v, K, dist)
    x, y = (uu - K[0, 2]) / K[0, 0], (vu - K[1, 2]) / K[1, 1]
    fg = np.isfinite(depth)
    with np.errstate(divide="ignore", invalid="ignore"):
        x1 = x - float(baseline) / np.where(fg, depth.astype(np.float64), np.inf)
        xd, yd = dist.distort(x1, y)
        xb, yb = dist.undistort(xd, yd)
        imaged = (np.abs(xb - x1) * K[0, 0] <= FOLD_TOL_PX) & (np.abs(yb - y) * K[1, 1] <= FOLD_TOL_PX)
    d = u - (xd * K[0, 0] + K[0, 2])
    return np.where(fg, np.where(imaged, d, np.nan), 0.0).astype(np.float32)


def semantic(instance: np.ndarray, class_of_instance: np.ndarray) -> np.ndarray:
    """Class id per pixel from the instance ids (``class_of_instance[id]``, 0 = background)."""
    return class_of_instance[instance].astype(np.int32)


def depth_euclidean(depth: np.ndarray, K: np.ndarray, dist: Distortion | None = None) -> np.ndarray:
    """Distance from the camera centre along each pixel's ray, depth * ||K^-1 [u, v, 1]|| ((u, v) undistorted
    through ``dist``: the ray the lens images at the pixel); inf where depth is."""
    h, w = depth.shape
    return (depth * ray_lengths(K, h, w, dist)).astype(np.float32)


def position(depth: np.ndarray, K: np.ndarray, cam_to_world: np.ndarray, dist: Distortion | None = None) -> np.ndarray:
    """World position of the surface at each pixel centre from planar depth and the pose (and the lens
    ``dist``: the point on the ray it images at the pixel) (float64 arithmetic, float32 result); NaN where
    there is no surface."""
    h, w = depth.shape
    u, v = pixel_grid(h, w, np.float64)
    fg = np.isfinite(depth)
    p = backproject(u, v, np.where(fg, depth, 0).astype(np.float64),
                    Camera(np.asarray(K, np.float64), np.asarray(cam_to_world, np.float64), dist))
    return np.where(fg[..., None], p, np.nan).astype(np.float32)


def circle_of_confusion(depth: np.ndarray, K: np.ndarray, aperture_m: float, focus_m: float, dist: Distortion | None = None) -> np.ndarray:
    """The ``coc`` key: the diameter in pixels of the disc a point at planar depth z is spread over by a
    thin lens of aperture diameter A focused on the plane at planar depth S, as Cycles renders it
    (its image plane at the focal length): f_px * A * |1/S - 1/z|; f_px * A / S where no surface (z = inf).

    Through a lens distortion ``dist`` the point spreads over the undistorted disc of diameter
    A * |1/S - 1/z| (normalised coordinates) about the pixel's undistorted (x, y), which the model images
    as an ellipse, that disc through its Jacobian M = diag(fx, fy) d(xd, yd)/d(x, y) at (x, y): the key is
    the ellipse's largest diameter, A * |1/S - 1/z| times M's largest singular value (f_px without distortion)."""
    K = np.asarray(K, np.float64)
    with np.errstate(divide="ignore"):
        inv = np.where(np.isfinite(depth), 1.0 / depth.astype(np.float64), 0.0)
    disc = aperture_m * np.abs(1.0 / focus_m - inv)  # the diameter in undistorted normalised coordinates
    if dist is None or dist.is_identity:
        return (float(K[0, 0]) * disc).astype(np.float32)
    h, w = depth.shape
    u, v = pixel_grid(h, w, np.float64)
    uu, vu = undistort_pixels(u, v, K, dist)
    a, b, c, d = dist.jacobian((uu - K[0, 2]) / K[0, 0], (vu - K[1, 2]) / K[1, 1])
    a, b, c, d = K[0, 0] * a, K[0, 0] * b, K[1, 1] * c, K[1, 1] * d
    frob, det = a * a + b * b + c * c + d * d, a * d - b * c
    sigma_max = np.sqrt(0.5 * (frob + np.sqrt(np.maximum(frob * frob - 4.0 * det * det, 0.0))))
    return (sigma_max * disc).astype(np.float32)


@dataclass(frozen=True)
class ViewInfo:
    """What a derived static key needs beside the stored keys: the view's K and pose, the rig baseline, the class
    table, the lens's (aperture diameter, focus distance) in metres for a render with --fstop, and the view's
    lens distortion for a render with --lens (None: a pinhole)."""

    K: np.ndarray
    baseline: float
    class_of_instance: np.ndarray
    cam_to_world: np.ndarray | None = None
    defocus: tuple[float, float] | None = None
    dist: Distortion | None = None


# Derived static keys (lfusd.keys.STATIC): name -> f(stored keys {depth, instance, ...}, ViewInfo).
DERIVED: dict[str, Callable[[dict, ViewInfo], np.ndarray]] = {
    "position": lambda raw, info: position(raw["depth"], info.K, info.cam_to_world, info.dist),
    "semantic": lambda raw, info: semantic(raw["instance"], info.class_of_instance),
    "disparity": lambda raw, info: (disparity(raw["depth"], float(info.K[0, 0]), info.baseline) if info.dist is None
                                    else disparity_distorted(raw["depth"], info.K, info.dist, info.baseline)),
    "depth_euclidean": lambda raw, info: depth_euclidean(raw["depth"], info.K, info.dist),
    "coc": lambda raw, info: circle_of_confusion(raw["depth"], info.K, *info.defocus, info.dist),
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


class LazyRawPasses:
    """:class:`RawPasses` whose images are decoded on first use (``load`` returns the RawPasses).

    The camera and the shape are known without decoding: a neighbouring frame whose occlusion is
    ray-cast against its triangles needs nothing else (lfusd.truth.motion.derive_motion), so each
    raw pass of a video is decoded once, for its own frame, not three times."""

    def __init__(self, camera: Camera, shape: tuple[int, int], load: Callable[[], RawPasses]):
        self.camera, self._shape, self._load, self._passes = camera, (int(shape[0]), int(shape[1])), load, None

    @property
    def shape(self) -> tuple[int, int]:
        return self._shape

    def _images(self) -> RawPasses:
        if self._passes is None:
            self._passes = self._load()
        return self._passes

    depth = property(lambda self: self._images().depth)
    vector = property(lambda self: self._images().vector)
    position = property(lambda self: self._images().position)
    instance = property(lambda self: self._images().instance)
    next_position = property(lambda self: self._images().next_position)
    prev_position = property(lambda self: self._images().prev_position)

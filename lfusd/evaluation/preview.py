"""Pictures of a dataset: flow colour wheel, disparity/depth colour maps, segmentation overlays,
a contact sheet of all views and an MP4 of the centre view over time with its flow beside it.

The flow colours follow Baker et al. (Middlebury, IJCV 2011) as in their ``colorcode.cpp``, computed
exactly as ``flow_vis`` does (see :func:`flow_to_color`): a 55-colour wheel (red-yellow 15, yellow-green 6, green-cyan 4, cyan-blue 11,
blue-magenta 13, magenta-red 6), hue from atan2(-v, -u), saturation from the magnitude over the
largest magnitude (white = no motion). With image coordinates (v down): flow to the right is red,
down is yellow-orange, left is cyan-blue and up is blue-violet.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from ..errors import LfusdError


def _cv2():
    import cv2

    return cv2


def make_colorwheel() -> np.ndarray:
    """The 55x3 Middlebury colour wheel (0..255)."""
    ry, yg, gc, cb, bm, mr = 15, 6, 4, 11, 13, 6
    wheel = np.zeros((ry + yg + gc + cb + bm + mr, 3))
    col = 0
    wheel[0:ry, 0] = 255
    wheel[0:ry, 1] = np.floor(255 * np.arange(ry) / ry)
    col += ry
    wheel[col : col + yg, 0] = 255 - np.floor(255 * np.arange(yg) / yg)
    wheel[col : col + yg, 1] = 255
    col += yg
    wheel[col : col + gc, 1] = 255
    wheel[col : col + gc, 2] = np.floor(255 * np.arange(gc) / gc)
    col += gc
    wheel[col : col + cb, 1] = 255 - np.floor(255 * np.arange(cb) / cb)
    wheel[col : col + cb, 2] = 255
    col += cb
    wheel[col : col + bm, 2] = 255
    wheel[col : col + bm, 0] = np.floor(255 * np.arange(bm) / bm)
    col += bm
    wheel[col : col + mr, 2] = 255 - np.floor(255 * np.arange(mr) / mr)
    wheel[col : col + mr, 0] = 255
    return wheel


def flow_to_color(flow, max_flow: float | None = None, valid=None) -> np.ndarray:
    """(H,W,2) flow -> (H,W,3) uint8 RGB on the Middlebury wheel; invalid / non-finite pixels black.

    Identical, level for level, to ``flow_vis.flow_to_color(flow)`` (Tom Runia's flow_vis, the
    colouring RAFT ships): u and v are divided by (largest valid magnitude + 1e-5), the radius is
    taken of the divided components, each channel is ``(1-f)*col0 + f*col1`` with col = wheel/255,
    desaturated as ``1 - rad*(1-col)`` inside the unit radius (``0.75*col`` outside) and stored as
    ``floor(255*col)``. Invalid pixels count as zero flow for the maximum, as if flow_vis were given
    them zeroed. ``max_flow`` replaces the largest magnitude (fixed colours across a video); flow
    beyond it is drawn darker, as flow_vis draws radii above 1.
    """
    f = np.asarray(flow, np.float64)
    if f.ndim != 3 or f.shape[2] != 2:
        raise LfusdError(f"flow images need (H,W,2) flow, got {f.shape}")
    ok = np.all(np.isfinite(f), axis=-1)
    if valid is not None:
        ok &= np.asarray(valid, bool)
    u = np.where(ok, f[..., 0], 0.0)
    v = np.where(ok, f[..., 1], 0.0)
    rad_max = float(max_flow) if max_flow else float(np.max(np.sqrt(np.square(u) + np.square(v))))
    u = u / (rad_max + 1e-5)
    v = v / (rad_max + 1e-5)
    img = _flow_uv_to_colors(u, v)
    img[~ok] = 0
    return img


def _flow_uv_to_colors(u: np.ndarray, v: np.ndarray) -> np.ndarray:
    """flow_vis' flow_uv_to_colors: the expression order matters to the level (floor of 255*col)."""
    wheel = make_colorwheel()
    n = wheel.shape[0]
    rad = np.sqrt(np.square(u) + np.square(v))
    a = np.arctan2(-v, -u) / np.pi
    fk = (a + 1) / 2 * (n - 1)
    k0 = np.floor(fk).astype(np.int32)
    k1 = k0 + 1
    k1[k1 == n] = 0
    w = fk - k0
    img = np.zeros(u.shape + (3,), np.uint8)
    inside = rad <= 1
    for i in range(3):
        col0 = wheel[k0, i] / 255.0
        col1 = wheel[k1, i] / 255.0
        col = (1 - w) * col0 + w * col1
        col = np.where(inside, 1 - rad * (1 - col), col * 0.75)  # beyond the largest radius: darker
        img[..., i] = np.floor(255 * col)
    return img


def colormap(values, vmin: float | None = None, vmax: float | None = None, name: str = "turbo", valid=None) -> np.ndarray:
    """Scalar map (H,W) -> (H,W,3) uint8 RGB with an OpenCV colour map; invalid pixels black.

    The range defaults to the 1st..99th percentile of the finite valid values.
    """
    cv2 = _cv2()
    x = np.asarray(values, np.float64)
    if x.ndim != 2:
        raise LfusdError(f"colour maps need an (H,W) array, got {x.shape}")
    ok = np.isfinite(x)
    if valid is not None:
        ok &= np.asarray(valid, bool)
    if not ok.any():
        return np.zeros(x.shape + (3,), np.uint8)
    lo = float(np.percentile(x[ok], 1)) if vmin is None else vmin
    hi = float(np.percentile(x[ok], 99)) if vmax is None else vmax
    if hi <= lo:
        hi = lo + 1e-9
    g = np.clip((np.where(ok, x, lo) - lo) / (hi - lo), 0, 1)
    maps = {"turbo": cv2.COLORMAP_TURBO, "viridis": cv2.COLORMAP_VIRIDIS, "inferno": cv2.COLORMAP_INFERNO, "magma": cv2.COLORMAP_MAGMA}
    if name not in maps:
        raise LfusdError(f"unknown colour map {name!r}; use one of {', '.join(maps)}")
    img = cv2.applyColorMap(np.round(g * 255).astype(np.uint8), maps[name])[..., ::-1].copy()
    img[~ok] = 0
    return img


def disparity_image(disp, valid=None) -> np.ndarray:
    """Disparity colour map (near = warm with turbo)."""
    return colormap(disp, name="turbo", valid=valid)


def depth_image(depth) -> np.ndarray:
    """Depth colour map on inverse depth, so that near is bright and the background (inf) black."""
    d = np.asarray(depth, np.float64)
    with np.errstate(divide="ignore"):
        inv = np.where(np.isfinite(d) & (d > 0), 1.0 / d, np.nan)
    return colormap(inv, name="magma")


def label_colors(n: int) -> np.ndarray:
    """n distinct RGB colours (golden-angle hues); id 0 is black."""
    cv2 = _cv2()
    hues = (np.arange(n) * 137.508) % 360
    hsv = np.stack([hues / 2, np.full(n, 200), np.full(n, 255)], -1).astype(np.uint8)[None]
    rgb = cv2.cvtColor(hsv, cv2.COLOR_HSV2RGB)[0]
    rgb[0] = 0
    return rgb


def segmentation_overlay(rgb, labels, alpha: float = 0.5) -> np.ndarray:
    """Blend a colour per label id over the image; label 0 (background / unlabelled) stays as is."""
    img = np.asarray(rgb)
    lab = np.asarray(labels)
    if img.shape[:2] != lab.shape:
        raise LfusdError(f"segmentation {lab.shape} does not match the image {img.shape[:2]}")
    ids, inv = np.unique(lab, return_inverse=True)
    pal = label_colors(max(int(ids.max()) + 1 if ids.size else 1, 1) if ids.max() < 4096 else len(ids) + 1)
    idx = lab if ids.max() < 4096 else inv.reshape(lab.shape) + 1
    col = pal[np.clip(idx, 0, len(pal) - 1)].astype(np.float64)
    out = img.astype(np.float64)
    fg = lab != 0
    out[fg] = (1 - alpha) * out[fg] + alpha * col[fg]
    # outline the label borders so touching regions stay apart
    edge = np.zeros(lab.shape, bool)
    edge[:-1] |= lab[:-1] != lab[1:]
    edge[:, :-1] |= lab[:, :-1] != lab[:, 1:]
    out[edge] = 255
    return np.clip(np.round(out), 0, 255).astype(np.uint8)


def contact_sheet(images: dict, rows: int, cols: int, max_width: int = 2048, gap: int = 2) -> np.ndarray:
    """Tile ``{(row, col): (H,W,3) uint8}`` into one image, the light-field grid as seen from behind."""
    cv2 = _cv2()
    first = next(iter(images.values()))
    h, w = first.shape[:2]
    s = min(1.0, (max_width - gap * (cols - 1)) / (cols * w))
    th, tw = max(1, int(round(h * s))), max(1, int(round(w * s)))
    sheet = np.full((rows * th + gap * (rows - 1), cols * tw + gap * (cols - 1), 3), 32, np.uint8)
    for (r, c), img in images.items():
        tile = img if (th, tw) == (h, w) else cv2.resize(img, (tw, th), interpolation=cv2.INTER_AREA)
        y, x = r * (th + gap), c * (tw + gap)
        sheet[y : y + th, x : x + tw] = tile
    return sheet


def write_video(path, frames: list[np.ndarray], fps: float = 12.0) -> Path:
    """Write RGB uint8 frames as an MP4 (MPEG-4 part 2, 'mp4v', OpenCV's bundled FFmpeg)."""
    cv2 = _cv2()
    path = Path(path)
    if not frames:
        raise LfusdError("no frames to write to a video; the dataset needs at least one frame")
    if path.suffix.lower() != ".mp4":
        raise LfusdError(f"videos are written as .mp4 (OpenCV's wheels have no GIF writer); rename {path.name}")
    h, w = frames[0].shape[:2]
    # mp4v needs even sizes in most players
    eh, ew = h - h % 2, w - w % 2
    vw = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*"mp4v"), fps, (ew, eh))
    if not vw.isOpened():
        from ..data.formats import why_unwritable

        raise LfusdError(f"could not open a video writer for {path}: {why_unwritable(path)}")
    for f in frames:
        vw.write(np.ascontiguousarray(f[:eh, :ew, ::-1]))
    vw.release()
    return path


def lens_shift(ds, view) -> np.ndarray | None:
    """(H, W) float64: how far, in pixels, each pixel of a view rendered through a lens distortion (--lens)
    lies from where a pinhole of the same K would image its ray; None for a pinhole."""
    from ..camera import pixel_grid, undistort_pixels

    dist = ds.distortion(view) if getattr(ds, "distorted", False) else None
    if dist is None or dist.is_identity:
        return None
    w, h = ds.resolution
    u, v = pixel_grid(h, w, np.float64)
    uu, vu = undistort_pixels(u, v, np.asarray(ds.intrinsics(view), np.float64), dist)
    return np.hypot(uu - u, vu - v)


def _try(read, *args):
    from ..errors import LfusdError as _E

    try:
        return read(*args)
    except (_E, KeyError, FileNotFoundError):
        return None


def preview(ds, dest, frame: int | None = None, video: bool = True, fps: float = 12.0) -> list[Path]:
    """Write the preview pictures of a dataset into ``dest`` (created if needed); returns the files."""
    from ..data.formats import write_png

    dest = Path(dest)
    frames = list(ds.frames)
    if not frames:
        raise LfusdError(f"dataset {getattr(ds, 'root', '')} has no completely rendered frame yet; finish its render first")
    if frame is not None and frame not in frames:
        raise LfusdError(f"frame {frame} is not in the dataset ({frames[0]}..{frames[-1]}); pick one of those")
    t = frames[0] if frame is None else frame
    c = tuple(ds.rig.centre_view)
    try:
        dest.mkdir(parents=True, exist_ok=True)
    except OSError as e:
        from ..data.formats import why_unwritable

        raise LfusdError(f"cannot create preview folder {dest} ({e.strerror}): {why_unwritable(dest)}") from None
    out: list[Path] = []

    def save(name, img):
        if img is None:
            return
        p = dest / name
        write_png(p, img)
        out.append(p)

    rgb = ds.read(t, c, "rgb")
    save(f"rgb_{t:04d}.png", rgb)
    disp = _try(ds.read, t, c, "disparity")
    depth = _try(ds.read, t, c, "depth")
    surface = None if depth is None else np.isfinite(depth)  # no surface (sky): black, outside the colour range
    save(f"disparity_{t:04d}.png", None if disp is None else disparity_image(disp, surface))
    save(f"depth_{t:04d}.png", None if depth is None else depth_image(depth))
    for key in ("instance", "semantic"):
        lab = _try(ds.read, t, c, key)
        save(f"{key}_{t:04d}.png", None if lab is None else segmentation_overlay(rgb, lab))
    # camera effects (docs/CONVENTIONS.md), where the dataset has them: the sensor's image, the
    # material masks over the image (1 transmissive, 2 mirror-like, 4 emissive, as label colours),
    # the depth behind transmissive surfaces, the motion-blur extent and the circle of confusion
    save(f"rgb_noisy_{t:04d}.png", _try(ds.read, t, c, "rgb_noisy"))
    masks = [_try(ds.read, t, c, k) for k in ("transmissive", "mirror", "emissive")]
    if all(m is not None for m in masks):
        save(f"materials_{t:04d}.png", segmentation_overlay(rgb, masks[0] * 1 + masks[1] * 2 + masks[2] * 4))
    behind = _try(ds.read, t, c, "depth_behind")
    save(f"depth_behind_{t:04d}.png", None if behind is None else depth_image(behind))
    for key in ("blur", "coc"):
        px = _try(ds.read, t, c, key)
        save(f"{key}_{t:04d}.png", None if px is None else colormap(px, vmin=0.0, name="turbo", valid=np.isfinite(px)))
    shift = lens_shift(ds, c)  # --lens: each pixel's distance from the pinhole's image of its ray
    save(f"lens_{t:04d}.png", None if shift is None else colormap(shift, vmin=0.0, name="turbo"))
    flow_max = None
    flows = {}
    for tt in frames:
        f = _try(ds.read, tt, c, "flow_fwd") if tt + 1 in frames else None
        if f is not None:
            valid = _try(ds.read, tt, c, "valid_fwd")
            flows[tt] = (f, valid)
            m = np.sqrt(np.sum(np.nan_to_num(f) ** 2, -1))
            flow_max = max(flow_max or 0.0, float(m.max()))
    if t in flows:
        save(f"flow_fwd_{t:04d}.png", flow_to_color(flows[t][0], flow_max or None, flows[t][1]))
    save(f"views_{t:04d}.png", contact_sheet({tuple(v): ds.read(t, tuple(v), "rgb") for v in ds.views}, ds.rig.rows, ds.rig.cols))
    if video and len(frames) > 1:
        seq = []
        for tt in frames:
            img = ds.read(tt, c, "rgb")
            fl = flows.get(tt)
            side = flow_to_color(fl[0], flow_max or None, fl[1]) if fl else np.zeros_like(img)
            seq.append(np.concatenate([img, side], axis=1))
        out.append(write_video(dest / "centre.mp4", seq, fps))
    return out

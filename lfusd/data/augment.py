"""Light-field augmentations that keep the ground truth consistent with the images.

Each function takes one item of :class:`lfusd.torch.LightFieldVideoDataset` (a dict of PyTorch
tensors, or NumPy arrays in the same layout: a key [V, *C, h, w], [T, V, *C, h, w] for clips;
``views``, ``offsets`` [V, 2], ``intrinsics`` [V, 3, 3], ``cam_to_world`` [V, 4, 4] or [T, V, 4, 4])
and returns a new item; the input is not changed. :class:`RandomLightField` draws them per item
(``LightFieldVideoDataset(..., transform=RandomLightField(...))``).

Geometry (docs/CONVENTIONS.md: a point at disparity d seen at (u, v) in the centre view appears at
(u - d*sx, v - d*sy) in the view with offsets (sx, sy)):

- :func:`refocus` ``k``: view i is shifted by (k*sx_i, k*sy_i) pixels, I'_i(u, v) = I_i(u - k*sx_i,
  v - k*sy_i), so every disparity becomes d - k (background at infinity: -k); the item is cropped
  by ``margin`` on each side so every view stays inside its image, and each view's principal point
  moves with its shift (depth, positions and flows are unchanged and stay exact).
- :func:`flip` ``"x"`` / ``"y"``: the image and the view grid are mirrored left-right / top-bottom
  (the array at grid position j now holds the mirror of the view at the mirrored position).
  Disparity keeps its value and sign; the u (v) component of ``flow_fwd`` / ``flow_bwd`` changes
  sign; the world is mirrored in the plane through the item's mean camera centre normal to the
  camera x (y) axis: ``position``, ``normal``, ``scene_flow`` and ``cam_to_world`` are mirrored with
  it (the camera frame stays right-handed: pose' = M pose D), ``intrinsics`` get cx' = w-1-cx.
- :func:`transpose`: image and grid transposed (u <-> v, row <-> col, sx <-> sy); flow components
  swap; the world is mirrored across the camera's x = y plane; fx <-> fy, cx <-> cy. Needs square
  pixels (fx = fy) and, for batches, square crops.
- :func:`translate_next` ``(dx, dy)``: frame t+1 of a two-frame clip translated by whole pixels
  against frame t: forward flow grows by (dx, dy), disparity and disparity change are unchanged
  (training a flow network on scenes whose camera stands still).
- :func:`colour_jitter` and :func:`noise` change ``rgb`` (and ``target_rgb``) only, float in [0, 1]
  (uint8 rgb, ``LightFieldVideoDataset(uint8_rgb=True)``, becomes float / 255 first):
  one brightness, contrast and saturation factor for all views and frames of an item (views must
  stay photo-consistent), independent Gaussian noise per pixel, clipped to [0, 1].

Flips and transposes need the set of views closed under the mirror (``all``, ``cross``,
``corners``, ``centre`` on a uniform grid); refocus needs integer shifts k*sx, k*sy. An item with
``target_rgb`` (angular super-resolution) takes only the colour augmentations. Blender's raw
``vector`` pass is refused. Imports only NumPy: PyTorch tensors are handled through their own
methods, so reading and augmenting stays free of torch where items are NumPy.
"""

from __future__ import annotations

import os

import numpy as np

from ..errors import LfusdError

_WORLD_POINTS = ("position", "next_position", "prev_position")  # affine: mirrored about a plane
_WORLD_VECTORS = ("normal", "scene_flow")  # linear part only
_FLOWS = ("flow_fwd", "flow_bwd")
_META = ("frames", "views", "offsets", "intrinsics", "cam_to_world", "crop", "target_views")


def _is_torch(a) -> bool:
    return type(a).__module__.startswith("torch")


def _np(a) -> np.ndarray:
    return a.detach().cpu().numpy() if _is_torch(a) else np.asarray(a)


def _like(x: np.ndarray, ref):
    """``x`` as the kind of array ``ref`` is (a tensor on ref's device and dtype, or NumPy of ref's dtype)."""
    if _is_torch(ref):
        return ref.new_tensor(np.ascontiguousarray(x), dtype=ref.dtype)
    return np.ascontiguousarray(x, dtype=ref.dtype)


def _take(a, idx, axis: int):
    """``a`` at positions ``idx`` along ``axis`` (a copy; NumPy or PyTorch alike)."""
    axis = axis % a.ndim
    return a[(slice(None),) * axis + (list(idx),)]


def _flip(a, axis: int):
    return a.flip((axis,)) if _is_torch(a) else np.flip(a, axis).copy()


def _swap_last(a):
    return a.transpose(-1, -2).contiguous() if _is_torch(a) else np.ascontiguousarray(np.swapaxes(a, -1, -2))


def _pixel_keys(item) -> list[str]:
    from ..keys import KEYS

    out = [k for k in item if k in KEYS]
    if "vector" in out:
        raise LfusdError("the raw 'vector' pass has no augmented form; leave it out of the keys to augment")
    return out


def _view_axis(item) -> int:
    return 0 if np.ndim(item["cam_to_world"]) == 3 else 1


def _channel_axis(key: str):
    """The channel axis of ``key`` in an item (counted from the end), or None for a scalar key."""
    from ..keys import KEYS

    return -3 if KEYS[key].shape else None


def _partners(offsets: np.ndarray, mirror) -> list[int]:
    """perm[j]: the view whose offsets, mirrored, are view j's; LfusdError when the set is not closed."""
    perm = []
    for j, o in enumerate(offsets):
        target = mirror(o)
        hits = np.flatnonzero(np.all(np.abs(offsets - target) < 1e-9, axis=1))
        if len(hits) != 1:
            raise LfusdError(f"the item's views have no mirror of the view at offsets {tuple(o)}; "
                             "use a view set that is symmetric on a uniform grid (all, cross, corners, centre)")
        perm.append(int(hits[0]))
    return perm


def _pinhole_only(item, what: str) -> None:
    """Refuse a geometric augmentation of views rendered through a lens distortion (``distortion``): the
    geometry above (disparity kept by a mirror, u - d*sx in every view) is a pinhole's."""
    if "distortion" in item and np.any(_np(item["distortion"])):
        raise LfusdError(f"{what} assumes pinhole views, and this item's were rendered through a lens distortion (--lens); "
                         "use only colour_jitter and noise (RandomLightField(flip=False)), or a dataset rendered without --lens")


def _no_targets(item, what: str) -> None:
    if "target_rgb" in item:
        raise LfusdError(f"{what} cannot move the target views of an angular super-resolution item; use only colour_jitter and noise there")


def _mirror(item, perm: list[int], d_cam: np.ndarray, image_op, channel_op) -> dict:
    """The shared part of flips and transposes: views reordered by ``perm``, every pixel key passed
    through ``image_op`` (and ``channel_op`` on its channel vector), the world mirrored by the
    4x4 M that makes every pose M T D (``d_cam``: the camera-frame reflection D)."""
    out = dict(item)
    vaxis = _view_axis(item)
    poses = _np(item["cam_to_world"]).astype(np.float64)
    first = poses if poses.ndim == 3 else poses[0]
    centre = first[:, :3, 3].mean(axis=0)
    rot = first[0, :3, :3]
    a = rot @ d_cam[:3, :3] @ rot.T  # the world reflection: the camera-frame one, in world axes
    m = np.eye(4)
    m[:3, :3], m[:3, 3] = a, centre - a @ centre
    new_poses = m @ np.take(poses, perm, axis=-3) @ d_cam
    out["cam_to_world"] = _like(new_poses, item["cam_to_world"])
    for k in _pixel_keys(item):
        v = image_op(_take(item[k], perm, vaxis))
        if k in _WORLD_POINTS or k in _WORLD_VECTORS:
            x = _np(v).astype(np.float64)
            x = np.einsum("ij,...jhw->...ihw", a, x)
            if k in _WORLD_POINTS:
                x = x + (centre - a @ centre)[:, None, None]
            v = _like(x, v)
        elif k in _FLOWS:
            v = channel_op(v)
        out[k] = v
    return out


def flip(item: dict, axis: str = "x") -> dict:
    """Mirror image and view grid left-right (``"x"``) or top-bottom (``"y"``); see the module docstring."""
    if axis not in ("x", "y"):
        raise LfusdError(f"flip axis {axis!r}: use 'x' (left-right) or 'y' (top-bottom)")
    _no_targets(item, "flip")
    _pinhole_only(item, "flip")
    c = 0 if axis == "x" else 1
    offsets = _np(item["offsets"]).astype(np.float64)
    sign = np.array([-1.0, 1.0]) if c == 0 else np.array([1.0, -1.0])
    perm = _partners(offsets, lambda o: o * sign)
    img_axis = -1 if c == 0 else -2
    d = np.diag([-1.0, 1.0, 1.0, 1.0]) if c == 0 else np.diag([1.0, -1.0, 1.0, 1.0])

    def negate_component(v):
        v = v.clone() if _is_torch(v) else v.copy()
        v[..., c, :, :] = -v[..., c, :, :]
        return v

    out = _mirror(item, perm, d, lambda v: _flip(v, img_axis), negate_component)
    size = _np(item[_pixel_keys(item)[0]]).shape[img_axis] if _pixel_keys(item) else None
    k = _np(item["intrinsics"]).astype(np.float64)[perm].copy()
    if size is None:
        raise LfusdError("the item holds no image key to flip")
    k[:, c, 2] = size - 1 - k[:, c, 2]
    out["intrinsics"] = _like(k, item["intrinsics"])
    return out


def transpose(item: dict) -> dict:
    """Transpose image and view grid (u <-> v, row <-> col); see the module docstring."""
    _no_targets(item, "transpose")
    _pinhole_only(item, "transpose")
    k = _np(item["intrinsics"]).astype(np.float64)
    if not np.allclose(k[:, 0, 0], k[:, 1, 1], rtol=1e-9):
        raise LfusdError("transpose needs square pixels (fx = fy) for one disparity in both directions; this item's differ")
    offsets = _np(item["offsets"]).astype(np.float64)
    perm = _partners(offsets, lambda o: o[::-1])
    p = np.eye(4)[[1, 0, 2, 3]]

    def swap_components(v):
        return _take(v, [1, 0], v.ndim - 3)

    out = _mirror(item, perm, p, _swap_last, swap_components)
    k = k[perm]
    kt = k.copy()
    kt[:, 0, 0], kt[:, 1, 1], kt[:, 0, 2], kt[:, 1, 2] = k[:, 1, 1], k[:, 0, 0], k[:, 1, 2], k[:, 0, 2]
    out["intrinsics"] = _like(kt, item["intrinsics"])
    return out


def refocus_margin(offsets, k_max: int) -> tuple[int, int]:
    """(rows, columns) that :func:`refocus` crops off each side for shifts up to ``|k| <= k_max``:
    ask the loader for crops this much larger on each side."""
    o = np.abs(np.asarray(offsets, np.float64))
    return int(np.ceil(k_max * o[:, 1].max() - 1e-9)), int(np.ceil(k_max * o[:, 0].max() - 1e-9))


def refocus(item: dict, k: int, margin: tuple[int, int] | None = None) -> dict:
    """Shift view i by (k*sx_i, k*sy_i) pixels (disparity d -> d - k) and crop ``margin`` (rows,
    columns; default :func:`refocus_margin` for ``|k|``) off each side; see the module docstring."""
    _no_targets(item, "refocus")
    _pinhole_only(item, "refocus")
    k = int(k)
    offsets = _np(item["offsets"]).astype(np.float64)
    shifts = k * offsets
    if not np.allclose(shifts, np.round(shifts), atol=1e-9):
        raise LfusdError(f"refocus by {k} needs integer shifts k*offset; this rig's offsets {sorted(set(offsets.ravel()))} give fractions")
    shifts = np.round(shifts).astype(int)
    my, mx = refocus_margin(offsets, abs(k)) if margin is None else (int(margin[0]), int(margin[1]))
    if np.abs(shifts[:, 1]).max() > my or np.abs(shifts[:, 0]).max() > mx:
        raise LfusdError(f"refocus by {k} shifts views by up to {np.abs(shifts).max()} px, more than the margin {my, mx}; give a larger margin")
    out = dict(item)
    vaxis = _view_axis(item)
    keys = _pixel_keys(item)
    if not keys:
        raise LfusdError("the item holds no image key to refocus")
    h, w = _np(item[keys[0]]).shape[-2:]
    hh, ww = h - 2 * my, w - 2 * mx
    if hh <= 0 or ww <= 0:
        raise LfusdError(f"a refocus margin of {my, mx} px leaves nothing of {h}x{w} crops; ask the loader for larger crops")
    for key in keys:
        a = item[key]
        shape = tuple(a.shape[:-2]) + (hh, ww)
        v = a.new_empty(shape) if _is_torch(a) else np.empty(shape, a.dtype)
        lead = (slice(None),) * vaxis
        for i, (sx, sy) in enumerate(shifts):
            v[lead + (i,)] = a[lead + (i,)][..., my - sy : my - sy + hh, mx - sx : mx - sx + ww]
        out[key] = v - k if key == "disparity" else v
    kk = _np(item["intrinsics"]).astype(np.float64).copy()
    kk[:, 0, 2] += shifts[:, 0] - mx
    kk[:, 1, 2] += shifts[:, 1] - my
    out["intrinsics"] = _like(kk, item["intrinsics"])
    if "crop" in item:
        crop = _np(item["crop"]).copy()
        crop[0] += my
        crop[1] += mx
        out["crop"] = _like(crop, item["crop"])  # the centre view's window in the source image
    return out


# what translate_next keeps exact: images and per-pixel labels move with the pixels; forward motion
# is re-expressed in the translated frame's pixels; what needs frame t+1's camera is refused
_TRANSLATABLE = ("rgb", "disparity", "depth", "disparity_change", "flow_fwd", "valid_fwd", "instance", "semantic", "mixed")


def translate_next(item: dict, dx: int, dy: int, margin: int) -> dict:
    """A two-frame clip with frame t+1 of every view translated by (dx, dy) whole pixels against frame
    t, I'_{t+1}(u, v) = I_{t+1}(u - dx, v - dy) (a crop of the ``margin`` px on each side at an
    offset; frame t is cropped alike at no offset): every pixel's forward flow t -> t+1 grows by
    exactly (dx, dy), while the disparity and the disparity change of each point are unchanged.
    Frame t+1's forward flow (to t+2, which is not translated) shrinks by (dx, dy). It teaches a
    flow network that every pixel may move (lfusd's ``things`` cameras stand still), but frame t+1
    is then no longer imaged by the item's intrinsics (its principal point moves by (dx, dy)), so
    keys that need its camera (positions, scene flow, backward flow) are refused."""
    _no_targets(item, "translate_next")
    _pinhole_only(item, "translate_next")
    dx, dy, m = int(dx), int(dy), int(margin)
    if max(abs(dx), abs(dy)) > m:
        raise LfusdError(f"a translation of ({dx}, {dy}) px needs a margin of at least {max(abs(dx), abs(dy))} px, got {m}")
    keys = _pixel_keys(item)
    other = [k for k in keys if k not in _TRANSLATABLE]
    if other:
        raise LfusdError(f"translate_next keeps {', '.join(_TRANSLATABLE)} exact, not {', '.join(other)}; leave those keys out")
    if _view_axis(item) != 1 or _np(item[keys[0]]).shape[0] != 2:
        raise LfusdError("translate_next takes a clip of two frames (LightFieldVideoDataset(clip=2))")
    h, w = _np(item[keys[0]]).shape[-2:]
    hh, ww = h - 2 * m, w - 2 * m
    if hh <= 0 or ww <= 0:
        raise LfusdError(f"a margin of {m} px leaves nothing of {h}x{w} crops; ask the loader for larger crops")
    out = dict(item)
    for key in keys:
        a = item[key]
        t0 = a[0][..., m : m + hh, m : m + ww]
        t1 = a[1][..., m - dy : m - dy + hh, m - dx : m - dx + ww]
        if key == "flow_fwd":
            d = np.array([dx, dy], np.float32).reshape(2, 1, 1)
            d = _like(d, a) if _is_torch(a) else d
            t0, t1 = t0 + d, t1 - d
        if _is_torch(a):
            out[key] = a.new_empty((2,) + tuple(t0.shape))
            out[key][0], out[key][1] = t0, t1
        else:
            out[key] = np.stack([t0, t1])
    if "crop" in item:
        crop = _np(item["crop"]).copy()
        crop[0] += m
        crop[1] += m
        out["crop"] = _like(crop, item["crop"])  # frame t's window in the source image
    return out


def _float_rgb(item) -> dict:
    """The item with ``rgb`` / ``target_rgb`` as float in [0, 1] (uint8 sRGB divided by 255, as the loader does)."""
    out = dict(item)
    for k in ("rgb", "target_rgb"):
        if k in item and _np(item[k][..., :1, :1]).dtype == np.uint8:
            out[k] = item[k].float() / 255.0 if _is_torch(item[k]) else item[k].astype(np.float32) / np.float32(255.0)
    return out


def colour_jitter(item: dict, brightness: float = 1.0, contrast: float = 1.0, saturation: float = 1.0) -> dict:
    """Scale brightness, contrast (about the item's mean grey) and saturation (about each pixel's
    grey, Rec. 709 weights) of ``rgb`` and ``target_rgb`` by the same factors in every view and frame."""
    item = _float_rgb(item)
    out = dict(item)
    keys = [k for k in ("rgb", "target_rgb") if k in item]
    if not keys:
        return out
    w = np.array([0.2126, 0.7152, 0.0722])
    ref = item["rgb"] if "rgb" in item else item[keys[0]]
    wt = _like(w.reshape(3, 1, 1), ref)
    mean = float(((ref * wt).sum(-3)).mean()) * brightness
    for k in keys:
        x = item[k] * brightness
        x = (x - mean) * contrast + mean
        grey = (x * wt).sum(-3, keepdims=True) if not _is_torch(x) else (x * wt).sum(-3, keepdim=True)
        x = grey + (x - grey) * saturation
        out[k] = x.clamp(0.0, 1.0) if _is_torch(x) else np.clip(x, 0.0, 1.0)
    return out


def noise(item: dict, sigma: float, rng: np.random.Generator | None = None) -> dict:
    """Add Gaussian noise of standard deviation ``sigma`` to ``rgb`` and ``target_rgb``, independently per pixel, view and frame."""
    item = _float_rgb(item)
    out = dict(item)
    rng = rng or np.random.default_rng()
    for k in ("rgb", "target_rgb"):
        if k not in item:
            continue
        x = item[k]
        n = _like(rng.normal(0.0, sigma, size=tuple(x.shape)), x)
        out[k] = (x + n).clamp(0.0, 1.0) if _is_torch(x) else np.clip(x + n, 0.0, 1.0)
    return out


class RandomLightField:
    """Random light-field augmentations for ``LightFieldVideoDataset(..., transform=...)``.

    ``refocus``: the largest |k| (shifts drawn uniformly from -k..k; the item is cropped by
    :func:`refocus_margin` for that k whatever is drawn, so items keep one size: ask the loader for
    crops 2*margin larger); ``flip``: flip x and y each with probability 1/2; ``transpose``: with
    probability 1/2 (square crops); ``brightness``, ``contrast``, ``saturation``: factors drawn
    uniformly in [1 - x, 1 + x]; ``noise``: the largest sigma (drawn in [0, noise]). ``seed``: a
    fixed seed; by default each process (DataLoader worker) draws its own from NumPy's global
    generator, which :func:`lfusd.torch.worker_init_fn` seeds."""

    def __init__(self, refocus: int = 0, flip: bool = True, transpose: bool = False, brightness: float = 0.0, contrast: float = 0.0,
                 saturation: float = 0.0, noise: float = 0.0, seed: int | None = None):
        self.refocus, self.flip, self.transpose = int(refocus), bool(flip), bool(transpose)
        self.brightness, self.contrast, self.saturation, self.noise = brightness, contrast, saturation, noise
        self.seed = seed
        self._rng: np.random.Generator | None = None
        self._pid = None

    def rng(self) -> np.random.Generator:
        """This process's generator (a forked worker makes its own)."""
        if self._rng is None or self._pid != os.getpid():
            self._pid = os.getpid()
            self._rng = np.random.default_rng(self.seed if self.seed is not None else np.random.randint(0, 2**63 - 1, dtype=np.int64))
        return self._rng

    def __call__(self, item: dict) -> dict:
        if self.refocus or self.flip or self.transpose:  # refused on every item, not on the draws that pick one
            _pinhole_only(item, "RandomLightField's refocus, flip and transpose")
        rng = self.rng()
        if self.refocus:
            k = int(rng.integers(-self.refocus, self.refocus + 1))
            item = refocus(item, k, margin=refocus_margin(_np(item["offsets"]), self.refocus))
        if self.flip:
            if rng.random() < 0.5:
                item = flip(item, "x")
            if rng.random() < 0.5:
                item = flip(item, "y")
        if self.transpose and rng.random() < 0.5:
            item = transpose(item)
        if self.brightness or self.contrast or self.saturation:
            f = [1.0 + rng.uniform(-x, x) if x else 1.0 for x in (self.brightness, self.contrast, self.saturation)]
            item = colour_jitter(item, *f)
        if self.noise:
            item = noise(item, float(rng.uniform(0.0, self.noise)), rng)
        return item

"""A PyTorch ``Dataset`` over a light-field video dataset folder (or any object with lfusd.Dataset's interface).

One item is one frame (or a clip of ``clip`` consecutive frames) with a chosen subset of views and
ground-truth keys, all views cropped with one window:

- any key of lfusd.keys, channels first: ``rgb`` (and ``rgb_noisy``) float32 [V,3,h,w] in [0, 1]; other float keys
  float32 [V,h,w] or [V,C,h,w] (``depth`` [V,h,w], ``flow_fwd`` [V,2,h,w], ``scene_flow`` [V,3,h,w]);
  integer keys (``instance``, ``semantic``) int64 [V,h,w]; masks (``valid_*``, ``occlusion_*``) bool [V,h,w].
  With ``clip > 1`` every key gains a leading time axis T.
- ``frames`` [T], ``views`` [V,2] (row, col), ``offsets`` [V,2] (sx, sy in baselines),
  ``intrinsics`` [V,3,3] (principal point moved by the crop), ``cam_to_world`` [V,4,4]
  ([T,V,4,4] for clips),
  ``crop`` [2] (top, left); from a dataset rendered with ``--lens``, ``distortion`` [V,5] (each view's OpenCV
  distCoeffs k1, k2, p1, p2, k3, which hold for the cropped K as well).
- With ``target_views`` (e.g. ``views="corners", target_views="all"`` for 2x2 -> 7x7 angular
  super-resolution) the item also holds ``target_rgb`` [Vt,3,h,w] and ``target_views``.

Keys of forward motion (t -> t+1) leave out the last frame, backward ones the first.

Fast reading: give a training cache (``lfusd export cache OUT DEST``, :mod:`lfusd.data.cache`)
instead of the dataset folder. The items are the same (the cache holds exactly what
``Dataset.read`` returns), but each key of a crop is one slice of a memory map for all views
(no decode, no whole image, no per-view copy). :func:`data_loader` builds a DataLoader with
seeded workers (:func:`worker_init_fn`) and pinned memory when asked; ``transform`` (e.g.
:class:`lfusd.data.augment.RandomLightField`) augments each item.
"""

from __future__ import annotations

import copy
import random
from pathlib import Path

import numpy as np
import torch
from torch.utils.data import DataLoader
from torch.utils.data import Dataset as _TorchDataset

from ..errors import LfusdError
from ..keys import KEYS as _REGISTRY

KEYS = tuple(_REGISTRY)
FORWARD = {k.name for k in _REGISTRY.values() if k.step > 0}  # defined only where frame t+1 exists
BACKWARD = {k.name for k in _REGISTRY.values() if k.step < 0}


def select_views(rig, views) -> list[tuple[int, int]]:
    """Resolve a view selection: 'all', 'centre', 'corners', 'cross' or a list of (row, col)."""
    allv = [(r, c) for r in range(rig.rows) for c in range(rig.cols)]
    if views is None or views == "all":
        return allv
    if views in ("centre", "center"):
        return [tuple(rig.centre_view)]
    if views == "corners":
        r, c = rig.rows - 1, rig.cols - 1
        return list(dict.fromkeys([(0, 0), (0, c), (r, 0), (r, c)]))
    if views == "cross":
        rc, cc = rig.centre_view
        return [v for v in allv if v[0] == rc or v[1] == cc]
    if isinstance(views, str):
        raise LfusdError(f"unknown view selection {views!r}; use all, centre, corners, cross or a list of (row, col)")
    out = [tuple(int(x) for x in v) for v in views]
    bad = [v for v in out if v not in allv]
    if bad:
        raise LfusdError(f"views {bad} are outside the {rig.rows}x{rig.cols} grid; use (row, col) inside it")
    return out


def worker_init_fn(worker_id: int) -> None:
    """Seed NumPy's and Python's global generators in a DataLoader worker from the seed PyTorch gave
    it, so that workers (and epochs) draw different crops and augmentations."""
    seed = torch.initial_seed() % 2**32
    np.random.seed(seed)
    random.seed(seed)


class _FloatRgbAfterCollation:
    """Collation that stacks uint8 ``rgb`` / ``target_rgb`` and only then divides by 255: the same
    float32 values as the items' own, at a third of the memory traffic (one pass over the batch)."""

    def __call__(self, items):
        from torch.utils.data import default_collate

        batch = default_collate(items)
        for k in ("rgb", "target_rgb"):
            if k in batch and batch[k].dtype == torch.uint8:
                batch[k] = torch.div(batch[k], 255.0)
        return batch


def data_loader(dataset, batch_size: int = 1, shuffle: bool = True, num_workers: int = 0, pin_memory: bool = False, **kw) -> DataLoader:
    """A ``torch.utils.data.DataLoader`` over ``dataset`` with :func:`worker_init_fn`, persistent
    workers and ``pin_memory`` (page-locked batches for fast copies to a GPU); ``kw`` go to DataLoader.

    Over a :class:`LightFieldVideoDataset` with float rgb and no transform, the items are read with
    uint8 rgb and the batch is converted once after collation (the same values, fewer bytes moved)."""
    kw.setdefault("worker_init_fn", worker_init_fn)
    if num_workers > 0:
        kw.setdefault("persistent_workers", True)
    if (batch_size is not None and "collate_fn" not in kw and isinstance(dataset, LightFieldVideoDataset)
            and not dataset.uint8_rgb and dataset.transform is None):
        dataset = copy.copy(dataset)
        dataset.uint8_rgb = True
        kw["collate_fn"] = _FloatRgbAfterCollation()
    return DataLoader(dataset, batch_size=batch_size, shuffle=shuffle, num_workers=num_workers,
                      pin_memory=pin_memory and torch.cuda.is_available(), **kw)


def _stacked_tensor(key: str, a: np.ndarray, uint8_rgb: bool = False) -> torch.Tensor:
    """A stacked [V, H, W, *C] array (a writable view of a copy-on-write map: no copy here) as the
    item's tensor [V, *C, H, W] (the values of :func:`_to_tensor`); collating the batch copies it once."""
    if a.dtype == bool:
        return torch.from_numpy(a)
    if np.issubdtype(a.dtype, np.integer) and key != "rgb":
        return torch.from_numpy(a.astype(np.int64))
    t = torch.from_numpy(a)
    if t.ndim == 4:
        t = t.permute(0, 3, 1, 2)
    if key == "rgb" and a.dtype == np.uint8:
        return t if uint8_rgb else torch.div(t, 255.0)  # one pass: uint8 -> float32 / 255, as _to_tensor
    return t if t.dtype == torch.float32 else t.to(torch.float32)


def _to_tensor(key: str, a: np.ndarray, uint8_rgb: bool = False) -> torch.Tensor:
    a = np.asarray(a)
    if not a.flags.writeable:  # e.g. images decoded by Pillow; torch wants writable memory
        a = a.copy()
    if key in ("rgb", "rgb_noisy"):  # 8-bit sRGB images
        t = torch.from_numpy(np.ascontiguousarray(a)).permute(2, 0, 1)
        if uint8_rgb and a.dtype == np.uint8:
            return t
        return t.to(torch.float32) / (255.0 if a.dtype == np.uint8 else 1.0)
    if a.dtype == bool:
        return torch.from_numpy(np.ascontiguousarray(a))
    if np.issubdtype(a.dtype, np.integer):
        return torch.from_numpy(a.astype(np.int64))
    t = torch.from_numpy(np.ascontiguousarray(a, dtype=np.float32))
    return t.permute(2, 0, 1) if t.ndim == 3 else t


class LightFieldVideoDataset(_TorchDataset):
    """``torch.utils.data.Dataset`` of light-field frames (see the module docstring for the items)."""

    def __init__(self, dataset, keys=("rgb",), views="all", frames=None, clip: int = 1, crop=None, random_crop: bool = False, target_views=None,
                 rig: str | None = None, transform=None, uint8_rgb: bool = False):
        """``dataset``: a dataset folder, a training cache folder (:mod:`lfusd.data.cache`) or an
        object reading like either; ``transform``: a callable applied to each item (an augmentation);
        ``uint8_rgb``: ``rgb`` (and ``target_rgb``) as the stored uint8 sRGB [V,3,h,w] rather than
        float32 in [0, 1] (a quarter of the bytes: divide by 255 on the GPU)."""
        if isinstance(dataset, (str, Path)):
            from .cache import TrainingCache, is_cache
            from .dataset import open_dataset

            dataset = TrainingCache(dataset) if is_cache(dataset) else open_dataset(dataset, rig)
        self.ds = dataset
        self.transform = transform
        self.uint8_rgb = bool(uint8_rgb)
        self.keys = tuple(keys)
        unknown = [k for k in self.keys if k not in KEYS]
        if unknown:
            raise LfusdError(f"unknown ground-truth keys {unknown}; use some of {', '.join(KEYS)}")
        self.views = select_views(dataset.rig, views)
        self.target_views = None if target_views is None else select_views(dataset.rig, target_views)
        if not isinstance(clip, int) or clip < 1:
            raise LfusdError(f"clip must be a positive number of frames, got {clip!r}")
        self.clip = clip
        all_frames = list(dataset.frames)
        use = list(all_frames if frames is None else frames)
        missing = [f for f in use if f not in all_frames]
        if missing:
            raise LfusdError(f"frames {missing} are not in the dataset ({all_frames[0]}..{all_frames[-1]})")
        fwd, bwd = bool(FORWARD & set(self.keys)), bool(BACKWARD & set(self.keys))
        # a clip starting at s covers s .. s+clip-1, all of them in the dataset and with their motion defined
        starts = []
        for i, s in enumerate(all_frames):
            seq = all_frames[i : i + clip]
            if len(seq) < clip or seq[0] not in use:
                continue
            if fwd and seq[-1] + 1 not in all_frames:
                continue
            if bwd and seq[0] - 1 not in all_frames:
                continue
            starts.append(i)
        self._starts = starts
        self._all_frames = all_frames
        h, w = dataset.rig.height, dataset.rig.width
        if crop is not None:
            ch, cw = (crop, crop) if isinstance(crop, int) else (int(crop[0]), int(crop[1]))
            if not (0 < ch <= h and 0 < cw <= w):
                raise LfusdError(f"crop {ch}x{cw} does not fit in the {h}x{w} images; give (height, width) no larger than the images")
            self.crop = (ch, cw)
        else:
            self.crop = None
        self.random_crop = random_crop
        # per-item constants, made once
        self._views_t = torch.tensor(self.views, dtype=torch.int64)
        self._offsets_t = torch.tensor([dataset.rig.offsets(v) for v in self.views], dtype=torch.float64)
        self._k = np.stack([np.array(dataset.intrinsics(v), dtype=np.float64) for v in self.views])
        self._dist = (torch.from_numpy(np.stack([dataset.distortion(v).coeffs for v in self.views]))
                      if getattr(dataset, "distorted", False) else None)

    def __len__(self) -> int:
        return len(self._starts)

    def _window(self):
        h, w = self.ds.rig.height, self.ds.rig.width
        if self.crop is None:
            return 0, 0, h, w
        ch, cw = self.crop
        if self.random_crop:
            y0 = int(torch.randint(0, h - ch + 1, ()).item())
            x0 = int(torch.randint(0, w - cw + 1, ()).item())
        else:
            y0, x0 = (h - ch) // 2, (w - cw) // 2
        return y0, x0, ch, cw

    def __getitem__(self, index: int) -> dict:
        if not 0 <= index < len(self):
            raise IndexError(index)
        i = self._starts[index]
        frames = self._all_frames[i : i + self.clip]
        y0, x0, ch, cw = self._window()

        fast = hasattr(self.ds, "window")  # a training cache: one slice of one map per key and frame

        def stack(key, views):
            per_t = []
            for t in frames:
                if fast:
                    per_t.append(_stacked_tensor(key, self.ds.window(t, key, views, y0, x0, ch, cw), self.uint8_rgb))
                else:
                    per_t.append(torch.stack([_to_tensor(key, self.ds.read(t, v, key), self.uint8_rgb)[..., y0 : y0 + ch, x0 : x0 + cw] for v in views]))
            return per_t[0] if self.clip == 1 else torch.stack(per_t)

        item = {k: stack(k, self.views) for k in self.keys}
        item["frames"] = torch.tensor(frames, dtype=torch.int64)
        item["views"] = self._views_t
        item["offsets"] = self._offsets_t
        ks = self._k.copy()
        ks[:, 0, 2] -= x0
        ks[:, 1, 2] -= y0
        item["intrinsics"] = torch.from_numpy(ks)
        if self._dist is not None:
            item["distortion"] = self._dist
        if fast:
            idx = self.ds._indices(self.views)
            poses = torch.from_numpy(np.stack([self.ds.maps(t, "cam_to_world")[idx] for t in frames]))
        else:
            poses = torch.from_numpy(np.stack([np.stack([np.asarray(self.ds.cam_to_world(t, v), np.float64) for v in self.views]) for t in frames]))
        item["cam_to_world"] = poses[0] if self.clip == 1 else poses
        item["crop"] = torch.tensor([y0, x0], dtype=torch.int64)
        if self.target_views is not None:
            item["target_rgb"] = stack("rgb", self.target_views)
            item["target_views"] = torch.tensor(self.target_views, dtype=torch.int64)
        return item if self.transform is None else self.transform(item)

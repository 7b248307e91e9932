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
  ``crop`` [2] (top, left).
- With ``target_views`` (e.g. ``views="corners", target_views="all"`` for 2x2 -> 7x7 angular
  super-resolution) the item also holds ``target_rgb`` [Vt,3,h,w] and ``target_views``.

Keys of forward motion (t -> t+1) leave out the last frame, backward ones the first.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import torch
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


def _to_tensor(key: str, a: np.ndarray) -> torch.Tensor:
    a = np.asarray(a)
    if not a.flags.writeable:  # e.g. images decoded by Pillow; torch wants writable memory
        a = a.copy()
    if key in ("rgb", "rgb_noisy"):  # 8-bit sRGB images
        t = torch.from_numpy(np.ascontiguousarray(a)).permute(2, 0, 1)
        return t.to(torch.float32) / (255.0 if a.dtype == np.uint8 else 1.0)
    if a.dtype == bool:
        return torch.from_numpy(np.ascontiguousarray(a))
    if np.issubdtype(a.dtype, np.integer):
        return torch.from_numpy(a.astype(np.int64))
    t = torch.from_numpy(np.ascontiguousarray(a, dtype=np.float32))
    return t.permute(2, 0, 1) if t.ndim == 3 else t


class LightFieldVideoDataset(_TorchDataset):
    """``torch.utils.data.Dataset`` of light-field frames (see the module docstring for the items)."""

    def __init__(self, dataset, keys=("rgb",), views="all", frames=None, clip: int = 1, crop=None, random_crop: bool = False, target_views=None, rig: str | None = None):
        if isinstance(dataset, (str, Path)):
            from .folder import open_dataset

            dataset = open_dataset(dataset, rig)
        self.ds = dataset
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

        def stack(key, views):
            per_t = []
            for t in frames:
                per_t.append(torch.stack([_to_tensor(key, self.ds.read(t, v, key))[..., y0 : y0 + ch, x0 : x0 + cw] for v in views]))
            return per_t[0] if self.clip == 1 else torch.stack(per_t)

        item = {k: stack(k, self.views) for k in self.keys}
        item["frames"] = torch.tensor(frames, dtype=torch.int64)
        item["views"] = torch.tensor(self.views, dtype=torch.int64)
        item["offsets"] = torch.tensor([self.ds.rig.offsets(v) for v in self.views], dtype=torch.float64)
        ks = []
        for v in self.views:
            k = np.array(self.ds.intrinsics(v), dtype=np.float64)
            k[0, 2] -= x0
            k[1, 2] -= y0
            ks.append(k)
        item["intrinsics"] = torch.from_numpy(np.stack(ks))
        poses = torch.from_numpy(np.stack([np.stack([np.asarray(self.ds.cam_to_world(t, v), np.float64) for v in self.views]) for t in frames]))
        item["cam_to_world"] = poses[0] if self.clip == 1 else poses
        item["crop"] = torch.tensor([y0, x0], dtype=torch.int64)
        if self.target_views is not None:
            item["target_rgb"] = stack("rgb", self.target_views)
            item["target_views"] = torch.tensor(self.target_views, dtype=torch.int64)
        return item

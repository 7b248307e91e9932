"""flow/train_disparity.py's training items (Augmented): drawn from the closed-form light field of
tests/support/fake.py (a wall at 0.8 px and a box at 1.5 px of disparity per view step), refocused by
0..shift_px of the scene's design and flipped / transposed with lfusd.data.augment, every item's
centre disparity still aligns its views (each view sampled at (u - d*sx, v - d*sy) shows the centre
view's colour, CONVENTIONS.md), the disparity takes both signs across items, the candidates' range
covers every shift, and a training cache that is not the scene's is refused in one line."""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import pytest

ROOT = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(ROOT / "flow"))
sys.path.insert(0, str(ROOT / "tests"))

import train_disparity  # noqa: E402
from support.fake import FakeDataset  # noqa: E402

from lfusd import LfusdError  # noqa: E402


def _bilinear(img: np.ndarray, u: np.ndarray, v: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    h, w = img.shape[-2:]
    inside = (u >= 0) & (u <= w - 1) & (v >= 0) & (v <= h - 1)
    u, v = np.clip(u, 0, w - 1), np.clip(v, 0, h - 1)
    x0, y0 = np.minimum(np.floor(u).astype(int), w - 2), np.minimum(np.floor(v).astype(int), h - 2)
    fx, fy = u - x0, v - y0
    out = (img[:, y0, x0] * (1 - fx) * (1 - fy) + img[:, y0, x0 + 1] * fx * (1 - fy) + img[:, y0 + 1, x0] * (1 - fx) * fy
           + img[:, y0 + 1, x0 + 1] * fx * fy)
    return out, inside


def test_items_are_refocused_flipped_and_still_align_their_views():
    fake = FakeDataset(rows=5, cols=5, width=48, height=48, frames=(1, 2))
    plain = dict(flip=True, transpose=True)  # colour and noise change no geometry; left out so that colours compare exactly
    items = train_disparity.Augmented([fake], [1], None, 24, 0, seed=3, augment=plain)
    assert train_disparity.refocus_shifts(1, 0) == [0, 1]
    seen = []
    y, x = np.mgrid[0:24, 0:24].astype(float)
    for n in range(12):
        views, rel, gt = items[n]
        assert views.shape == (25, 3, 24, 24) and rel.shape == (25, 2) and gt.shape == (24, 24)
        d = gt.numpy().astype(float)
        seen.append(d)
        centre = views[12].numpy()
        fg = np.abs(d - np.median(d)) < 1e-3  # pixels on one plane, away from the box's edges in every view
        for i in (0, 4, 7, 20, 24):
            sx, sy = rel[i].tolist()

            def err(dd):  # median colour error (robust to the few pixels the box hides in view i)
                got, inside = _bilinear(views[i].numpy(), x - dd * sx, y - dd * sy)
                assert (inside & fg).sum() > 50
                return float(np.median(np.abs(got - centre)[:, inside & fg]))

            # the texture is fine (about 2 rad per pixel), so bilinear sampling is not exact: compare with wrong disparities
            assert err(d) < 0.5 * min(err(d + 0.4), err(d - 0.4), err(-d)), (n, i)
    d = np.concatenate([s.ravel() for s in seen])
    assert d.min() < -0.1 and d.max() > 0.4  # wall at 0.8 - 1, box at 1.5 (and 1.5 - 1 = 0.5)
    lo, hi = train_disparity.disparity_range(fake, [1, 2], shifts=[0, 1])
    assert lo < 0.8 - 1 and hi > 1.5


def test_a_cache_of_another_scene_is_refused(tmp_path):
    from lfusd.data.cache import write_cache

    write_cache(FakeDataset(rows=3, cols=3, width=24, height=20, frames=(1, 2)), tmp_path / "c", keys=("rgb", "disparity"))
    with pytest.raises(LfusdError, match="is not one of .* make it with .lfusd export cache") as e:
        train_disparity.scene_source(tmp_path / "scene", tmp_path / "c", FakeDataset(rows=5, cols=5, width=24, height=20, frames=(1, 2)))
    assert "\n" not in str(e.value)
    other = FakeDataset(rows=3, cols=3, width=24, height=20, frames=(1, 2))
    other.rig_name = "rig_01"  # the same shape, another rig of the scene
    with pytest.raises(LfusdError, match="is not one of"):
        train_disparity.scene_source(tmp_path / "scene", tmp_path / "c", other)
    got = train_disparity.scene_source(tmp_path / "scene", tmp_path / "c", FakeDataset(rows=3, cols=3, width=24, height=20, frames=(1, 2)))
    assert got.rig.rows == 3

"""Exposure (issue 39.19b): a render whose images are nearly black or overexposed is said so, and
the documented automatic exposure is one gain per dataset that brings them into range."""

from __future__ import annotations

import numpy as np
import pytest

from support.fake import FakeDataset

from lfusd.data.exposure import BRIGHT_TARGET, auto_gain, exposed, exposure_problems


def srgb8(linear):
    """IEC 61966-2-1, clipped and rounded: written here from the standard."""
    x = np.clip(np.asarray(linear, np.float64), 0, 1)
    return np.rint(255 * np.where(x <= 0.0031308, 12.92 * x, 1.055 * x ** (1 / 2.4) - 0.055)).astype(np.uint8)


class LitFake(FakeDataset):
    """The analytic scene rendered at ``light`` times its texture's linear radiance (as a stage lit
    by a DistantLight of intensity 3 renders at 0.0015, or an overlit one at 24)."""

    def __init__(self, light: float, **kw):
        super().__init__(**kw)
        self.light = light

    def read(self, frame, view, key):
        if key == "rgb_linear":
            tex = super().read(frame, view, "rgb").astype(np.float64) / 255.0
            return (self.light * tex ** 2.2).astype(np.float32)
        if key == "rgb":
            return srgb8(self.read(frame, view, "rgb_linear"))
        return super().read(frame, view, key)


def lit(light):
    return LitFake(light, rows=3, cols=3, width=24, height=20, frames=(1, 2, 3))


def test_dark_and_overexposed_datasets_are_said_and_a_normal_one_is_not():
    dark = exposure_problems(lit(0.0015))
    assert len(dark) == 1 and "nearly black" in dark[0] and "--exposure auto" in dark[0]
    bright = exposure_problems(lit(24.0))
    assert len(bright) == 1 and "overexposed" in bright[0] and "% of pixels are white" in bright[0]
    assert exposure_problems(lit(1.0)) == []
    still = lit(0.0015)
    still.keys = ("rgb", "depth")  # no linear image kept: nothing to judge, nothing said
    assert exposure_problems(still) == []


@pytest.mark.parametrize("light", [0.0015, 24.0])
def test_auto_exposure_is_one_gain_per_dataset_putting_the_bright_end_below_white(light):
    ds = lit(light)
    c = ds.rig.centre_view
    lin = np.concatenate([ds.read(t, c, "rgb_linear").reshape(-1, 3).astype(np.float64) for t in ds.frames])
    lum = lin @ [0.2126, 0.7152, 0.0722]
    gain = BRIGHT_TARGET / np.percentile(lum, 99)
    assert auto_gain(ds) == pytest.approx(gain, rel=1e-6)
    e = exposed(ds, "auto")
    for t in ds.frames:
        for v in ((0, 0), c, (2, 2)):  # every view and frame: the same gain
            want = srgb8(ds.read(t, v, "rgb_linear").astype(np.float64) * e.gain)
            assert np.abs(e.read(t, v, "rgb").astype(int) - want.astype(int)).max() <= 1
    img = e.read(1, c, "rgb")
    assert np.percentile(img.max(axis=-1), 99) >= 200 and np.mean(np.all(img == 255, axis=-1)) < 0.05  # bright, not white
    assert e.read(1, c, "depth").shape == (20, 24)  # other keys as stored
    assert exposed(ds, "2").gain == 2.0
    with pytest.raises(Exception, match="positive gain"):
        exposed(ds, "-1")


def test_export_with_automatic_exposure_writes_visible_images(tmp_path, monkeypatch, capsys):
    from lfusd.cli import main
    from lfusd.data import formats
    import lfusd.data.dataset

    ds = lit(0.0015)
    monkeypatch.setattr(lfusd.data.dataset, "open_dataset", lambda path, rig=None: ds)
    assert main(["export", "hci", "/data/dark", str(tmp_path / "plain")]) == 0
    assert main(["export", "hci", "/data/dark", str(tmp_path / "auto"), "--exposure", "auto"]) == 0
    assert "gain" in capsys.readouterr().out
    dark = formats.read_png(next((tmp_path / "plain").rglob("input_Cam004.png")))
    seen = formats.read_png(next((tmp_path / "auto").rglob("input_Cam004.png")))
    assert dark.max() < 32 and np.percentile(seen.max(axis=-1), 99) >= 200

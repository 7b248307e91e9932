"""The camera effects' settings are checked before any work: one-line errors naming the fix."""

from __future__ import annotations

from pathlib import Path

import pytest

from lfusd import LfusdError
from lfusd.data.sensor import SensorModel
from lfusd.render.request import RenderRequest


def _req(**kw) -> RenderRequest:
    return RenderRequest(stage=Path("s.usda"), out=Path("o"), motion=True, **kw)


@pytest.mark.parametrize("kw,match", [
    (dict(shutter=1.5), "--shutter 1.5 is not a fraction"),
    (dict(shutter=-0.1), "--shutter"),
    (dict(fstop=2.8), "--fstop and --focus go together"),
    (dict(focus=3.0), "--fstop and --focus go together"),
    (dict(fstop=-1.0, focus=3.0), "--fstop -1.0 is not a non-negative number"),
    (dict(fstop=float("nan"), focus=3.0), "--fstop nan"),
    (dict(keys=("rgb", "coc")), "--keys coc: made only with --fstop"),
    (dict(keys=("blur",)), "--keys blur: made only with --shutter"),
    (dict(keys=("depth_behind",)), "--keys depth_behind: made only with --materials"),
])
def test_impossible_effect_settings_are_refused_in_one_line(kw, match):
    with pytest.raises(LfusdError, match=match) as e:
        _req(**kw).check()
    assert "\n" not in str(e.value)


def test_effects_that_need_a_video_are_refused_for_a_still():
    for kw, what in ((dict(shutter=0.5), "--shutter"), (dict(materials=True), "--materials")):
        with pytest.raises(LfusdError, match=what):
            RenderRequest(stage=Path("s.usda"), out=Path("o"), **kw).check()


def test_each_effect_adds_its_keys_and_no_other():
    base = set(_req().stored_keys())
    assert set(_req(shutter=0.5).stored_keys()) - base == {"blur"}
    assert set(_req(fstop=2.8, focus=3.0).stored_keys()) - base == {"coc"}
    # the raw flags pass `material` is kept only with --keep-raw, like every raw pass
    assert set(_req(materials=True).stored_keys()) - base == {"transmissive", "mirror", "emissive", "depth_behind"}
    assert set(_req(materials=True, keep_raw=True).stored_keys()) - set(_req(keep_raw=True).stored_keys()) == {
        "material", "transmissive", "mirror", "emissive", "depth_behind"}
    assert set(_req(sensor=SensorModel(iso=800)).stored_keys()) - base == {"rgb_noisy"}

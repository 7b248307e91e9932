"""Format version 2 on tiny real renders: what each view folder holds, --keys, --keep-raw, and verify on the stored keys."""

from __future__ import annotations

import json

import numpy as np
import OpenEXR
import pytest
from support.cli import assert_one_line_error, run_cli
from support.scenes import write_motion_stage

from lfusd import Dataset, LfusdError, layout
from lfusd.camera import RigSpec
from lfusd.data import integrity
from lfusd.truth.motion import MOTION_KEYS

pytestmark = pytest.mark.render

# 128x96: verify's occlusion limit needs this much (at 64x48 silhouettes are 1-2 % of the pixels)
RIG = RigSpec(name="main", rows=1, cols=2, width=128, height=96, baseline=0.1, at=(0.3, -5.0, 1.8), look_at=(0.0, 0.5, 0.6))
TINY = ("--samples", "1", "--quiet", "--device", "cpu")


@pytest.fixture(scope="module")
def stage(tmp_path_factory):
    path = tmp_path_factory.mktemp("store") / "movers.usda"
    write_motion_stage(path, RIG, 3, (0.05, -0.03, 0.0))  # the stage's range is frames 1-3
    return path


def _files(out, frame, view=(0, 0)):
    return sorted(p.name for p in (layout.frame_dir(out, "main", frame) / layout.view_key(view)).iterdir())


def test_default_render_stores_the_keys_checks_them_and_drops_the_raw_passes(stage, capsys):
    out = stage.parent / "default"
    code, text, err = run_cli(capsys, "render-video", stage, "-o", out, *TINY)
    assert code == 0, err
    for f in (1, 2, 3):
        assert _files(out, f) == sorted([layout.RGB_EXR, layout.GT_FILE, layout.MOTION_FILE, layout.VIEW_RECORD]), f
        rec = integrity.read_record(layout.frame_dir(out, "main", f) / "00_01")
        # read back and compared before the raw passes went: one count per key and pixel
        assert rec["files"][layout.GT_FILE]["checked"] == 3 * RIG.width * RIG.height
        assert rec["files"][layout.MOTION_FILE]["checked"] == len(MOTION_KEYS) * RIG.width * RIG.height  # every motion key (no camera effect's)
        assert rec["files"][layout.PASSES_EXR]["removed"] and rec["files"][layout.PASSES_EXR]["pixels"]
    manifest = json.loads((out / layout.MANIFEST).read_text())
    assert manifest["version"] == 2 and manifest["settings"]["keep_raw"] is False and "flow_fwd" in manifest["settings"]["keys"]
    ds = Dataset(out)
    assert ds.read(2, (0, 1), "position").shape == (RIG.height, RIG.width, 3)
    with pytest.raises(LfusdError, match="--keep-raw"):
        ds.read(2, (0, 1), "vector")
    code, text, err = run_cli(capsys, "verify", out)
    assert code == 0, text + err  # verify passes on the stored (compressed) keys
    assert run_cli(capsys, "verify", out, "--integrity")[0] == 0
    code, _, err = run_cli(capsys, "derive", out)
    assert_one_line_error(code, err, "raw passes", "--keep-raw")
    code, text, err = run_cli(capsys, "render-video", stage, "-o", out, *TINY)  # a rerun: nothing to render or derive
    assert code == 0 and "motion derived for 0 views" in text, text + err


def test_keys_subset_with_keep_raw_writes_only_those(stage, capsys):
    out = stage.parent / "subset"
    code, _, err = run_cli(capsys, "render-video", stage, "-o", out, "--resolution", "32x24", "--keys", "rgb,depth,flow_fwd,valid_fwd",
                           "--keep-raw", *TINY)
    assert code == 0, err
    for f in (1, 2, 3):
        # --keep-raw keeps the raw files: Blender's passes and the frame's rendered triangles
        assert _files(out, f) == sorted([layout.RGB_PNG, layout.GT_FILE, layout.MOTION_FILE, layout.PASSES_EXR, layout.GEOMETRY,
                                         layout.VIEW_RECORD]), f
    d = layout.frame_dir(out, "main", 2) / "00_00"
    assert set(OpenEXR.File(str(d / layout.GT_FILE)).channels()) == {"depth"}
    assert set(OpenEXR.File(str(d / layout.MOTION_FILE)).channels()) == {"flow_fwd.X", "flow_fwd.Y", "masks"}
    settings = json.loads((out / layout.MANIFEST).read_text())["settings"]
    assert settings["keys"] == ["rgb", "depth", "flow_fwd", "valid_fwd"] and settings["keep_raw"] is True
    ds = Dataset(out)
    assert ds.read(2, (0, 0), "rgb").dtype == np.uint8 and ds.read(2, (0, 0), "vector").shape == (24, 32, 4)
    raw_depth = ds.raw_passes(2, (0, 0)).depth
    np.testing.assert_array_equal(ds.read(2, (0, 0), "depth"), raw_depth)  # depth is stored losslessly
    for key in ("normal", "rgb_linear", "flow_bwd"):
        with pytest.raises(LfusdError, match=f"key '{key}' was not written .*--keys") as e:
            ds.read(2, (0, 0), key)
        assert "\n" not in str(e.value)
    assert run_cli(capsys, "derive", out)[0] == 0  # the raw passes are kept: motion derives again


def test_bad_keys_are_one_line_usage_errors(stage, tmp_path, capsys):
    for keys, words in (("rgb,dpeth", ("unknown ground-truth key 'dpeth'",)), ("vector", ("--keep-raw",)), (",", ("names no key",))):
        code, _, err = run_cli(capsys, "render-video", stage, "-o", tmp_path / "x", "--keys", keys, *TINY)
        assert_one_line_error(code, err, *words)
    code, _, err = run_cli(capsys, "render", stage, "-o", tmp_path / "x", "--keys", "flow_fwd", *TINY)
    assert_one_line_error(code, err, "render-video")
    assert not (tmp_path / "x").exists()

"""render-video --lens / --lens-seed / --lens-spread up to the worker, without Blender: the options, the
request's checks, the manifest's per-view lenses, and a folding model refused in one line before anything is written."""

from __future__ import annotations

import argparse
from dataclasses import replace
from types import SimpleNamespace

import numpy as np
import pytest
from support.distortion_stage import LENS, RIG, write_distortion_stage

from lfusd.camera import Distortion, check_distortion, view_distortion
from lfusd.errors import LfusdError
from lfusd.layout import view_key
from lfusd.render.request import RenderRequest


def test_a_folding_lens_is_refused_in_one_line_and_nothing_is_written(tmp_path, capsys):
    from lfusd.cli import main

    write_distortion_stage(tmp_path / "d.usda")
    out = tmp_path / "out"
    assert main(["render-video", str(tmp_path / "d.usda"), "-o", str(out), "--quiet", "--lens", "-0.3,0,0,0,0"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "folds over the image" in err[0] and "smaller coefficients" in err[0], err
    assert not out.exists()


def test_the_options_parse_into_the_request_and_are_checked():
    from lfusd.commands import args as argtypes

    assert argtypes.lens_model("-0.25,0.05,0.003,-0.004,0.002") == LENS
    for bad in ("1,2,3", "a,b,c,d,e", "nan,0,0,0,0"):
        with pytest.raises(argparse.ArgumentTypeError):
            argtypes.lens_model(bad)
    req = dict(stage="s.usda", out="o", motion=True)
    for fields, words in ((dict(lens_seed=1, lens_spread=0.1), "add --lens"),
                          (dict(lens=LENS, lens_seed=1), "go together"),
                          (dict(lens=LENS, lens_spread=0.1), "go together"),
                          (dict(lens=LENS, lens_seed=1, lens_spread=-1.0), "--lens-spread")):
        with pytest.raises(LfusdError, match=words):
            RenderRequest(**req, **fields).check()
    RenderRequest(**req, lens=LENS, lens_seed=1, lens_spread=0.05).check()
    for device in ("cuda", "optix"):  # the OSL camera is checked on the CPU only
        with pytest.raises(LfusdError, match="--device cpu"):
            RenderRequest(**req, lens=LENS, device=device).check()
    RenderRequest(**req, lens=LENS, device="auto").check()
    RenderRequest(**req, lens=LENS, fstop=2.8, focus=3.0).check()  # the OSL camera has its own thin lens
    assert RenderRequest(**req, lens=LENS).distorted and not RenderRequest(**req, lens=Distortion()).distorted


def test_the_manifest_records_each_views_own_lens_drawn_from_the_seed():
    from lfusd.render.job import _lens_record, _lenses_of

    rig = replace(RIG, rows=2, cols=2)
    req = RenderRequest(stage="s.usda", out="o", motion=True, lens=LENS, lens_seed=7, lens_spread=0.05)
    rec = _lens_record(req, [SimpleNamespace(spec=rig)])
    views = rec["views"]["main"]
    assert rec["model"] == LENS.to_dict() and rec["seed"] == 7 and len(views) == 4
    for view in rig.views:
        assert Distortion.from_dict(views[view_key(view)]) == view_distortion(LENS, view, 7, 0.05)  # reproducible per (seed, view)
    assert len({tuple(sorted(d.items())) for d in views.values()}) == 4  # each view its own lens
    lenses = _lenses_of({"lens": rec, "rigs": {"main": rig.to_dict()}})
    assert np.allclose(lenses["main"][view_key((0, 0))]["K"], rig.intrinsics()) and lenses["main"][view_key((1, 1))]["dist"] == views[view_key((1, 1))]


def test_a_drawn_lens_that_folds_is_refused_naming_the_view():
    from lfusd.camera import rig_distortions

    base = Distortion(k1=-0.2)
    check_distortion(base, RIG.intrinsics(), RIG.width, RIG.height)  # the base model alone is fine
    with pytest.raises(LfusdError, match=r"folds over the image .*view \d,\d of rig main, drawn with --lens-seed 3"):
        rig_distortions(RIG, base, seed=3, spread=2.0)


def test_the_certificate_names_every_camera_effect_of_the_settings():
    from lfusd.data.certificate import camera_effects

    assert camera_effects({"samples": 4}) == {}
    sensor = {"iso": 800.0, "jpeg": 0, "vignetting": 0.3, "seed": 2}
    lens = {"model": LENS.to_dict(), "seed": 3, "spread": 0.05, "views": {"main": {}}}
    got = camera_effects({"shutter": 0.5, "defocus": {"fstop": 2.8, "focus": 3.0}, "sensor": sensor, "materials": True, "lens": lens})
    assert got == {"motion_blur": {"shutter": 0.5}, "defocus": {"fstop": 2.8, "focus": 3.0}, "sensor_noise": sensor,
                   "material_masks": True, "lens_distortion": {"model": LENS.to_dict(), "seed": 3, "spread": 0.05}}


def test_a_recipe_asks_for_the_lens_and_the_card_says_so():
    import json
    from dataclasses import asdict

    from lfusd.recipe import effects_text, parse_recipe

    ds = {"name": "x", "grid": [3, 3], "resolution": [64, 64]}
    part = [{"name": "a", "templates": ["room"], "scenes": 1}]
    r = parse_recipe({"dataset": {**ds, "lens": [-0.1, 0.01, 0, 0, 0], "lens_seed": 2, "lens_spread": 0.05}, "part": part})
    assert (r.distortion, r.distortion_seed, r.distortion_spread) == ((-0.1, 0.01, 0.0, 0.0, 0.0), 2, 0.05)
    said = effects_text(json.loads(json.dumps(asdict(r))))
    assert "lens distortion k1, k2, p1, p2, k3 = -0.1, 0.01, 0, 0, 0" in said and "seed 2" in said
    assert "lens" not in effects_text(json.loads(json.dumps(asdict(parse_recipe({"dataset": ds, "part": part})))))
    for bad, words in (({"lens": [1, 2]}, "dataset.lens must be"), ({"lens": [-0.1, 0, 0, 0, 0], "lens_seed": 1}, "go together"),
                       ({"lens_seed": 1, "lens_spread": 0.1}, "add dataset.lens")):
        with pytest.raises(LfusdError, match=words):
            parse_recipe({"dataset": {**ds, **bad}, "part": part})
    both = parse_recipe({"dataset": {**ds, "lens": [-0.1, 0, 0, 0, 0], "fstop": 2.8, "focus": 3.0}, "part": part})
    assert both.distortion[0] == -0.1 and both.lens == (2.8, 3.0)  # distortion and defocus together


def test_geometric_augmentations_refuse_distorted_views_and_colour_ones_keep_them():
    from lfusd.data.augment import RandomLightField, colour_jitter, flip, refocus, transpose

    item = {"rgb": np.zeros((2, 3, 4, 4), np.float32), "disparity": np.zeros((2, 4, 4), np.float32),
            "views": np.array([[0, 0], [0, 1]]), "offsets": np.array([[-0.5, 0.0], [0.5, 0.0]]),
            "intrinsics": np.stack([np.eye(3)] * 2), "cam_to_world": np.stack([np.eye(4)] * 2),
            "distortion": np.stack([LENS.coeffs] * 2)}
    for op in (lambda i: flip(i, "x"), transpose, lambda i: refocus(i, 1), RandomLightField(seed=0)):
        with pytest.raises(LfusdError, match="lens distortion"):
            op(item)
    assert np.array_equal(colour_jitter(item, brightness=1.1)["distortion"], item["distortion"])
    pinhole = {**item, "distortion": np.zeros((2, 5))}
    assert flip(pinhole, "x")["rgb"].shape == (2, 3, 4, 4)


def test_a_bench_definition_with_a_lens_is_refused_before_anything_renders(tmp_path, monkeypatch):
    import lfusd.bench.make as make

    text = (make.DEFINITIONS / "tiny.toml").read_text()
    assert "[dataset]\n" in text
    (tmp_path / "lensy.toml").write_text(text.replace("[dataset]\n", "[dataset]\nlens = [-0.1, 0.0, 0.0, 0.0, 0.0]\n", 1))
    monkeypatch.setattr(make, "DEFINITIONS", tmp_path)
    with pytest.raises(LfusdError, match="dataset.lens renders distorted scenes, and a benchmark needs pinhole cameras"):
        make.load_definition("lensy")
    out = tmp_path / "bench"
    with pytest.raises(LfusdError, match="dataset.lens"):
        make.make_bench("lensy", out)
    assert not out.exists()


def test_coc_through_a_lens_is_the_disc_imaged_through_the_models_jacobian():
    """lfusd.data.passes.circle_of_confusion against OpenCV's projectPoints differentiated numerically."""
    import cv2

    from lfusd.camera import pixel_grid
    from lfusd.data.passes import circle_of_confusion

    K = RIG.intrinsics()
    h, w = RIG.height, RIG.width
    z = np.linspace(0.5, 6.0, h * w).reshape(h, w)
    z[0, 0] = np.inf  # no surface: the disc of a point at infinity
    aperture, focus = 0.02, 2.0
    pinhole = circle_of_confusion(z, K, aperture, focus)
    np.testing.assert_allclose(pinhole, K[0, 0] * aperture * np.abs(1 / focus - 1 / z), rtol=1e-6)
    np.testing.assert_array_equal(circle_of_confusion(z, K, aperture, focus, Distortion()), pinhole)
    got = circle_of_confusion(z, K, aperture, focus, LENS)
    u, v = pixel_grid(h, w, np.float64)
    pts = np.stack([u, v], -1).reshape(-1, 1, 2)
    xy = cv2.undistortPointsIter(pts, K, LENS.coeffs, None, None, (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 200, 1e-14))[:, 0]
    e = 1e-6

    def proj(p):
        uv, _ = cv2.projectPoints(np.concatenate([p, np.ones((len(p), 1))], 1)[:, None], np.zeros(3), np.zeros(3), K, LENS.coeffs)
        return uv[:, 0]

    M = np.stack([(proj(xy + [e, 0]) - proj(xy - [e, 0])) / (2 * e), (proj(xy + [0, e]) - proj(xy - [0, e])) / (2 * e)], -1)
    want = aperture * np.abs(1 / focus - 1 / z.ravel()) * np.linalg.svd(M, compute_uv=False)[:, 0]
    np.testing.assert_allclose(got.ravel(), want, rtol=1e-5)
    assert (got[pinhole > 0.01] / pinhole[pinhole > 0.01]).min() < 0.9  # the barrel lens shrinks the blur towards the corners


def test_the_lens_shader_is_a_thin_lens_only_when_asked():
    from lfusd.render.lens import osl_source

    K = RIG.intrinsics()
    pinhole = osl_source(LENS, K, RIG.width, RIG.height)
    assert "camera_shader_random_sample" not in pinhole and "position = point(0, 0, 0);" in pinhole
    thin = osl_source(LENS, K, RIG.width, RIG.height, aperture_radius=0.0125, focus=3.0)
    assert "camera_shader_random_sample" in thin and "0.0125" in thin and "* 3.0 - vector(position)" in thin
    for radius, focus in ((-0.01, 3.0), (0.01, 0.0)):
        with pytest.raises(ValueError, match="thin lens"):
            osl_source(LENS, K, RIG.width, RIG.height, aperture_radius=radius, focus=focus)

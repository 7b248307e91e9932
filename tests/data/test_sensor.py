"""The sensor model of rgb_noisy (lfusd.data.sensor) against its documented formulas: the noise's mean and
variance per level, the vignetting and the per-camera variation, reproducibility for a seed, and the key
read from a dataset folder."""

from __future__ import annotations

import json

import numpy as np
import OpenEXR
import pytest

from lfusd import Dataset, LfusdError, layout
from lfusd.camera import RigSpec
from lfusd.data import integrity, sensor
from lfusd.data.passes import linear_to_srgb8
from lfusd.data.sensor import SensorModel
from lfusd.keys import check_wanted

FLAT = dict(gain_spread=0.0, colour_spread=0.0, vignetting=0.0)  # a camera whose response is 1 everywhere


@pytest.mark.parametrize("iso", [100, 1600])
def test_noise_mean_and_variance_per_level_match_the_poisson_gaussian_model(iso):
    model = SensorModel(iso=iso, read_noise=4.0, **FLAT)
    q = model.full_well * 100 / iso  # electrons per unit: the docstring's formula, by hand
    for level in (0.0, 0.01, 0.05, 0.2, 0.5, 0.8):
        y = sensor.expose(model, np.full((200, 200, 3), level, np.float32), (0, 0), frame=1)
        n = y.size
        var = level / q + (4.0 / q) ** 2
        assert abs(y.mean() - level) < 5 * np.sqrt(var / n), (iso, level, y.mean())
        # the sample variance of n normal-ish values has relative sd sqrt(2 / n): 5 of them, and room for Poisson skew
        assert abs(y.var() / var - 1) < 5 * np.sqrt(2 / n) + 0.005, (iso, level, y.var(), var)


def test_mean_follows_gain_colour_and_vignetting_and_the_variance_follows_the_mean():
    model = SensorModel(iso=800, gain_spread=0.1, colour_spread=0.05, vignetting=0.5, seed=7)
    h, w, level = 60, 80, 0.3
    r = sensor.view_response(model, (1, 2))
    frames = np.stack([sensor.expose(model, np.full((h, w, 3), level), (1, 2), f) for f in range(200)])
    # the model's mean signal, by hand: g * c * (1 - k r^2) * level at each pixel centre
    v, u = np.mgrid[0:h, 0:w] + 0.5
    r2 = ((u - w / 2) ** 2 + (v - h / 2) ** 2) / ((w / 2) ** 2 + (h / 2) ** 2)
    s = r.gain * r.colour * (1 - r.vignetting * r2)[..., None] * level
    q = model.electrons_per_unit
    var = s / q + (model.read_noise / q) ** 2
    z = (frames.mean(axis=0) - s) / np.sqrt(var / len(frames))  # standard scores of each pixel's mean
    assert abs(z.mean()) < 0.05 and abs(z.std() - 1) < 0.05
    assert abs((frames.var(axis=0) / var).mean() - 1) < 0.01
    assert r.vignetting > 0 and s[0, 0, 1] < s[h // 2, w // 2, 1]  # the corners are darker


def test_vignette_at_hand_computed_pixels():
    v = sensor.ViewResponse(1.0, np.ones(3), 0.4).vignette(2, 4)
    # pixel (0, 0): centre (0.5, 0.5), offset (-1.5, -0.5) from (2, 1); half diagonal^2 = 4 + 1
    assert v[0, 0] == pytest.approx(1 - 0.4 * (2.25 + 0.25) / 5)
    assert v[1, 2] == pytest.approx(1 - 0.4 * (0.25 + 0.25) / 5)


def test_each_camera_of_a_rig_has_its_own_response_spread_as_the_model_says_and_fixed_for_a_seed():
    model = SensorModel(gain_spread=0.1, colour_spread=0.05, vignetting=0.3, seed=3)
    views = [(r, c) for r in range(9) for c in range(9)]
    gains = np.array([sensor.view_response(model, v).gain for v in views])
    colours = np.array([sensor.view_response(model, v).colour for v in views])
    assert len(set(gains.round(12))) == len(views)  # every camera differs
    assert abs(np.log(gains).std() / 0.1 - 1) < 0.25  # 81 draws: the sd of the sd is about 8 %
    assert abs(np.log(colours).std() / 0.05 - 1) < 0.2
    again = sensor.view_response(SensorModel(gain_spread=0.1, colour_spread=0.05, vignetting=0.3, seed=3), (4, 5))
    assert again.gain == sensor.view_response(model, (4, 5)).gain
    assert sensor.view_response(SensorModel(seed=4), (4, 5)).gain != sensor.view_response(SensorModel(seed=3), (4, 5)).gain


def test_noisy_image_is_reproducible_for_a_seed_and_fresh_per_frame():
    rng = np.random.default_rng(0)
    clean = rng.uniform(0, 1, (16, 24, 3)).astype(np.float32)
    m = SensorModel(iso=3200, seed=5)
    a = sensor.noisy_srgb(m, clean, (0, 1), 10)
    assert a.dtype == np.uint8 and a.shape == (16, 24, 3)
    assert np.array_equal(a, sensor.noisy_srgb(SensorModel(iso=3200, seed=5), clean, (0, 1), 10))
    assert not np.array_equal(a, sensor.noisy_srgb(m, clean, (0, 1), 11))
    assert not np.array_equal(a, sensor.noisy_srgb(SensorModel(iso=3200, seed=6), clean, (0, 1), 10))
    assert not np.array_equal(a, sensor.noisy_srgb(m, clean, (0, 1), -10))  # negative frames have their own noise


def test_a_noiseless_flat_camera_gives_the_clean_srgb_image_and_jpeg_stays_close():
    rng = np.random.default_rng(1)
    clean = rng.uniform(0, 1, (32, 32, 3)).astype(np.float32)
    # no read noise and a huge well: the Poisson term's sd is 1e-5, far below half an 8-bit step
    m = SensorModel(full_well=1e12, read_noise=0.0, **FLAT)
    out = sensor.noisy_srgb(m, clean, (0, 0), 1)
    assert np.abs(out.astype(int) - linear_to_srgb8(clean).astype(int)).max() <= 1
    smooth = np.broadcast_to(np.linspace(0.05, 0.9, 32)[None, :, None], (32, 32, 3)).astype(np.float32)
    jpeg = sensor.noisy_srgb(SensorModel(full_well=1e12, read_noise=0.0, jpeg=95, **FLAT), smooth, (0, 0), 1)
    assert np.abs(jpeg.astype(int) - linear_to_srgb8(smooth).astype(int)).mean() < 2


def test_saturation_clips_at_white():
    out = sensor.noisy_srgb(SensorModel(iso=100, **FLAT), np.full((8, 8, 3), 5.0, np.float32), (0, 0), 1)
    assert (out == 255).all()


@pytest.mark.parametrize("field,value", [("iso", 0), ("vignetting", 0.99), ("jpeg", 101), ("seed", -1), ("read_noise", float("nan"))])
def test_impossible_parameters_are_refused_in_one_line(field, value):
    with pytest.raises(LfusdError, match=f"sensor {field}"):
        SensorModel(**{field: value}).check()


def test_rgb_noisy_is_a_key_only_of_renders_with_a_sensor():
    assert "rgb_noisy" not in check_wanted(None, motion=True, keep_raw=False)
    assert "rgb_noisy" in check_wanted(None, motion=True, keep_raw=False, effects=("sensor",))
    with pytest.raises(LfusdError, match="--iso"):
        check_wanted(("rgb", "rgb_noisy"), motion=False, keep_raw=False)


RIG = RigSpec(name="main", rows=1, cols=2, width=12, height=10)


def _dataset(root, settings_extra: dict):
    keys = ["rgb", "rgb_linear", "rgb_noisy"] if settings_extra else ["rgb", "rgb_linear"]
    manifest = {"format": layout.FORMAT, "version": layout.FORMAT_VERSION, "rigs": ["main"], "frames": [3], "complete": {"main": [3]},
                "settings": {"rigs": {"main": RIG.to_dict()}, "keys": keys, **settings_extra}}
    root.mkdir(parents=True)
    (root / layout.MANIFEST).write_text(json.dumps(manifest))
    (root / layout.OBJECTS).write_text(json.dumps({"classes": ["unlabelled"], "objects": []}))
    d = layout.frame_dir(root, "main", 3)
    d.mkdir(parents=True)
    pose = np.eye(4).tolist()
    (d / layout.FRAME_META).write_text(json.dumps({"cam_to_world": {layout.view_key(v): pose for v in RIG.views}, "object_poses": {}}))
    clean = np.random.default_rng(2).uniform(0, 1, (10, 12, 3)).astype(np.float16)
    for v in RIG.views:
        (d / layout.view_key(v)).mkdir()
        OpenEXR.File({"compression": OpenEXR.ZIP_COMPRESSION, "type": OpenEXR.scanlineimage},
                     {"RGB": clean}).write(str(d / layout.view_key(v) / layout.RGB_EXR))
        integrity.record_files(d / layout.view_key(v), {layout.RGB_EXR: {}}, ())
    return root, clean.astype(np.float32)


def test_dataset_reads_rgb_noisy_with_the_recorded_model(tmp_path):
    model = SensorModel(iso=1600, jpeg=0, seed=9)
    root, clean = _dataset(tmp_path / "ds", {"sensor": model.to_dict()})
    ds = Dataset(root)
    assert ds.frames == [3]
    got = ds.read(3, (0, 1), "rgb_noisy")
    assert np.array_equal(got, sensor.noisy_srgb(model, clean, (0, 1), 3))
    assert not np.array_equal(got, ds.read(3, (0, 0), "rgb_noisy"))  # another camera, another response and noise
    assert np.array_equal(ds.read(3, (0, 1), "rgb_linear"), clean)  # the clean image stays


def test_dataset_without_a_sensor_says_how_to_get_rgb_noisy(tmp_path):
    root, _ = _dataset(tmp_path / "ds", {})
    with pytest.raises(LfusdError, match="rgb_noisy"):
        Dataset(root).read(3, (0, 0), "rgb_noisy")


RECIPE = """
[dataset]
name = "n"
grid = [1, 2]
resolution = [16, 16]
{sensor}
[[part]]
name = "p"
templates = ["room"]
scenes = 1
"""


def test_a_recipe_turns_the_sensor_on_with_its_table_and_the_render_request_carries_it(tmp_path):
    from lfusd.recipe import parse_recipe
    import tomllib

    assert parse_recipe(tomllib.loads(RECIPE.format(sensor=""))).sensor is None
    r = parse_recipe(tomllib.loads(RECIPE.format(sensor="[dataset.sensor]\niso = 800\njpeg = 90\nseed = 4\n")))
    assert r.sensor == SensorModel(iso=800, jpeg=90, seed=4)
    for bad, match in (("iso = 0", "dataset.sensor iso"), ("gain = 1", "dataset.sensor.gain"), ("jpeg = 9.5", "dataset.sensor.jpeg")):
        with pytest.raises(LfusdError, match=match):
            parse_recipe(tomllib.loads(RECIPE.format(sensor=f"[dataset.sensor]\n{bad}\n")))


def test_render_video_options_build_the_sensor_model_and_refuse_its_options_without_iso():
    import argparse

    from lfusd.commands import args as argtypes

    p = argtypes.Parser()
    argtypes.add_effect_options(p)
    assert argtypes.sensor_model(p.parse_args([])) is None
    assert argtypes.sensor_model(p.parse_args(["--iso", "400", "--jpeg", "80", "--sensor-seed", "2"])) == SensorModel(iso=400, jpeg=80, seed=2)
    with pytest.raises(LfusdError, match="--iso"):
        argtypes.sensor_model(p.parse_args(["--jpeg", "80"]))
    with pytest.raises(LfusdError, match="sensor jpeg"):
        argtypes.sensor_model(p.parse_args(["--iso", "400", "--jpeg", "200"]))
    assert isinstance(p, argparse.ArgumentParser)


def test_the_card_says_which_camera_effects_the_dataset_has():
    from dataclasses import asdict
    import tomllib

    from lfusd.recipe import effects_text, parse_recipe

    plain = json.loads(json.dumps(asdict(parse_recipe(tomllib.loads(RECIPE.format(sensor=""))))))
    assert effects_text(plain).startswith("none")
    text = RECIPE.format(sensor="shutter = 0.5\nfstop = 2.8\nfocus = 3.0\nmaterials = true\n[dataset.sensor]\niso = 800\njpeg = 90\n")
    r = json.loads(json.dumps(asdict(parse_recipe(tomllib.loads(text)))))
    said = effects_text(r)
    for part in ("motion blur over 0.5", "f/2.8 focused at 3 m", "ISO 800", "JPEG 90", "material masks"):
        assert part in said, said

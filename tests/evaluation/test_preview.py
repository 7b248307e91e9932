"""Preview pictures: the Middlebury colour wheel convention, and images that are neither blank nor saturated."""

from __future__ import annotations

import numpy as np
import pytest

from support.fake import FakeDataset
from lfusd import LfusdError
from lfusd.evaluation import preview
from support.spec_readers import read_png_spec


@pytest.mark.parametrize(
    "flow, expected",
    [
        # Hand-computed from Baker et al.'s colorcode.cpp (fk = (atan2(-v,-u)/pi + 1)/2 * 54):
        ((1.0, 0.0), (255, 0, 0)),  # right: atan2(-0.0, -1) = -pi, wheel[0], red (as flow_vis)
        ((1.0, 1e-3), (255, 0, 0)),  # right, a hair down: just past wheel[0], red
        ((1.0, -1e-3), (255, 0, 43)),  # right, a hair up: wheel[54], magenta->red segment, red
        ((0.0, 1.0), (255, 229, 0)),  # down (v grows downward): between wheel[13] and [14], yellow-orange
        ((-1.0, 0.0), (0, 209, 255)),  # left: wheel[27], cyan->blue segment
        ((0.0, -1.0), (88, 0, 255)),  # up: between wheel[40] and [41], blue-violet
    ],
)
def test_colour_wheel_directions(flow, expected):
    f = np.zeros((1, 2, 2))
    f[0, 0] = flow  # the other pixel (zero flow) must be white
    img = preview.flow_to_color(f)
    assert np.all(np.abs(img[0, 0].astype(int) - expected) <= 1), img[0, 0]
    assert tuple(img[0, 1]) == (255, 255, 255)


def test_colour_wheel_on_rotation_field():
    """A field rotating about the image centre: hue runs around the wheel, saturation grows outward."""
    n = 65
    y, x = np.mgrid[0:n, 0:n] - (n - 1) / 2.0
    flow = np.stack([-y, x], -1)  # x right, y down: clockwise on screen
    img = preview.flow_to_color(flow).astype(int)
    c = (n - 1) // 2
    assert tuple(img[c, c]) == (255, 255, 255)
    # right of centre the flow points down (yellow), left of it up (blue-violet),
    # above it right (red), below it left (cyan-blue)
    r, g, b = img[c, n - 3]
    assert r > b + 100 and g > b + 100
    r, g, b = img[c, 2]
    assert b > r + 100 and b > g + 100
    r, g, b = img[2, c]
    assert r > g + 100 and r > b + 100
    r, g, b = img[n - 3, c]
    assert g > r + 100 and b > r + 100
    # saturation (1 - min channel/255) grows with radius along a ray
    sat = 255 - img[c, c:].min(axis=-1)
    assert np.all(np.diff(sat[1:]) >= 0)
    assert abs(int(sat[-1]) - 255 * (n - 1) / 2 / np.hypot(c, c)) <= 2  # linear in radius / max radius


def test_invalid_flow_is_black():
    f = np.ones((2, 2, 2))
    f[0, 0] = np.nan
    img = preview.flow_to_color(f, valid=np.array([[True, True], [False, True]]))
    assert tuple(img[0, 0]) == (0, 0, 0) and tuple(img[1, 0]) == (0, 0, 0)
    with pytest.raises(LfusdError):
        preview.flow_to_color(np.zeros((2, 2)))


def _looks_like_a_picture(img, white_ok=False):
    """Not blank (varied), not saturated (mostly neither black nor white). Flow images are white
    where nothing moves (the Middlebury convention), so for them only coloured content is required."""
    img = np.asarray(img)
    assert img.ndim == 3 and img.shape[2] == 3
    assert img.std() > 10, "blank"
    assert np.mean(np.all(img == 0, -1)) < 0.5, "saturated to black"
    if white_ok:
        assert np.mean(img.max(-1).astype(int) - img.min(-1) > 60) > 0.05, "no coloured pixels"
    else:
        assert np.mean(img == 255) < 0.5, "saturated to white"
        assert 20 < img.mean() < 235


def test_preview_writes_pictures_and_video(tmp_path):
    ds = FakeDataset(rows=3, cols=3, width=40, height=32, frames=(1, 2, 3))
    files = preview.preview(ds, tmp_path / "prev")
    names = {p.name for p in files}
    for n in ("rgb_0001.png", "disparity_0001.png", "depth_0001.png", "instance_0001.png", "semantic_0001.png", "flow_fwd_0001.png", "views_0001.png", "centre.mp4"):
        assert n in names
    for p in files:
        if p.suffix == ".png":
            _looks_like_a_picture(read_png_spec(p), white_ok=p.name.startswith("flow"))
    sheet = read_png_spec(tmp_path / "prev" / "views_0001.png")
    assert sheet.shape == (3 * 32 + 4, 3 * 40 + 4, 3)
    np.testing.assert_array_equal(sheet[34:66, 42:82], ds.read(1, (1, 1), "rgb"))  # the centre tile
    import cv2

    cap = cv2.VideoCapture(str(tmp_path / "prev" / "centre.mp4"))
    n = 0
    while True:
        ok, frame = cap.read()
        if not ok:
            break
        n += 1
        assert frame.shape == (32, 80, 3)
    assert n == 3


def test_video_needs_mp4(tmp_path):
    with pytest.raises(LfusdError):
        preview.write_video(tmp_path / "a.gif", [np.zeros((8, 10, 3), np.uint8)])


def test_segmentation_overlay_keeps_background_and_tints_labels():
    rgb = np.full((6, 6, 3), 100, np.uint8)
    lab = np.zeros((6, 6), np.int32)
    lab[3:, 3:] = 5
    out = preview.segmentation_overlay(rgb, lab)
    np.testing.assert_array_equal(out[0, 0], rgb[0, 0])
    assert np.any(out[5, 5] != rgb[5, 5])
    with pytest.raises(LfusdError):
        preview.segmentation_overlay(rgb, lab[:3])

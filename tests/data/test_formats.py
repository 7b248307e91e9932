"""File formats: bytes checked with readers written from the specs (tests/support/spec_readers.py)."""

from __future__ import annotations

import struct

import numpy as np
import pytest

from lfusd import LfusdError
from lfusd.data import formats
from support.spec_readers import read_flo_spec, read_hci_cfg_spec, read_pfm_spec, read_png_spec

RNG = np.random.default_rng(3)


def test_pfm_header_and_bottom_up_little_endian(tmp_path):
    a = np.arange(6, dtype=np.float32).reshape(2, 3)  # top row 0 1 2, bottom row 3 4 5
    p = tmp_path / "a.pfm"
    formats.write_pfm(p, a)
    data = p.read_bytes()
    assert data.startswith(b"Pf\n3 2\n-1.0\n")
    body = data[len(b"Pf\n3 2\n-1.0\n") :]
    assert struct.unpack("<6f", body) == (3.0, 4.0, 5.0, 0.0, 1.0, 2.0)  # bottom row first


@pytest.mark.parametrize("shape", [(7, 5), (4, 6, 3)])
def test_pfm_round_trip(tmp_path, shape):
    a = RNG.normal(size=shape).astype(np.float32)
    a.flat[0] = np.inf
    p = tmp_path / "a.pfm"
    formats.write_pfm(p, a)
    np.testing.assert_array_equal(read_pfm_spec(p), a)
    np.testing.assert_array_equal(formats.read_pfm(p), a)


def test_pfm_reader_handles_big_endian(tmp_path):
    a = RNG.normal(size=(3, 4)).astype(np.float32)
    p = tmp_path / "be.pfm"
    p.write_bytes(b"Pf\n4 3\n1.0\n" + a[::-1].astype(">f4").tobytes())
    np.testing.assert_array_equal(formats.read_pfm(p), a)


def test_flo_round_trip_and_bytes(tmp_path):
    f = RNG.normal(0, 5, (5, 7, 2)).astype(np.float32)
    p = tmp_path / "a.flo"
    formats.write_flo(p, f)
    assert p.read_bytes()[:4] == b"PIEH"
    np.testing.assert_array_equal(read_flo_spec(p), f)
    np.testing.assert_array_equal(formats.read_flo(p), f)


def test_kitti_flow_png_round_trip_within_precision(tmp_path):
    f = RNG.normal(0, 40, (9, 11, 2))
    valid = RNG.random((9, 11)) > 0.3
    p = tmp_path / "flow.png"
    formats.write_kitti_flow(p, f, valid)
    raw = read_png_spec(p)  # channels in file order R, G, B
    assert raw.dtype == np.uint16 and raw.shape == (9, 11, 3)
    np.testing.assert_array_equal(raw[..., 2] > 0, valid)
    u = (raw[..., 0].astype(float) - 2**15) / 64.0
    v = (raw[..., 1].astype(float) - 2**15) / 64.0
    assert np.max(np.abs(u[valid] - f[..., 0][valid])) <= 1 / 128 + 1e-9
    assert np.max(np.abs(v[valid] - f[..., 1][valid])) <= 1 / 128 + 1e-9
    back, bvalid = formats.read_kitti_flow(p)
    np.testing.assert_array_equal(bvalid, valid)
    assert np.max(np.abs(back[valid] - f[valid])) <= 1 / 128 + 1e-9


def test_kitti_disparity_png_round_trip_within_precision(tmp_path):
    d = RNG.uniform(0.5, 200, (8, 10))
    d[0, 0] = np.inf
    p = tmp_path / "disp.png"
    formats.write_kitti_disparity(p, d)
    raw = read_png_spec(p)
    assert raw.dtype == np.uint16 and raw.ndim == 2
    ok = np.isfinite(d)
    assert raw[0, 0] == 0
    assert np.max(np.abs(raw[ok] / 256.0 - d[ok])) <= 1 / 512 + 1e-9
    back, valid = formats.read_kitti_disparity(p)
    np.testing.assert_array_equal(valid, ok)
    assert np.max(np.abs(back[ok] - d[ok])) <= 1 / 512 + 1e-6


def test_rgb_png_channel_order(tmp_path):
    img = np.zeros((4, 5, 3), np.uint8)
    img[..., 0] = 200  # red
    img[1, 2] = (1, 2, 3)
    p = tmp_path / "rgb.png"
    formats.write_png(p, img)
    np.testing.assert_array_equal(read_png_spec(p), img)
    np.testing.assert_array_equal(formats.read_png(p), img)


def test_hci_config_round_trip(tmp_path):
    params = {k: 1.5 for keys in formats.HCI_KEYS.values() for k in keys}
    params.update(image_resolution_x_px=512, image_resolution_y_px=384, num_cams_x=9, num_cams_y=9, scene="boxes", category="training", date="2016", version="1.0", authors=["a b", "c d"], contact="x@y", cycles_seed=0)
    params["center_cam_rx_rad"] = 1.5707963267948966
    p = tmp_path / "parameters.cfg"
    formats.write_hci_config(p, params)
    spec = read_hci_cfg_spec(p)
    assert spec["width"] == 512 and spec["height"] == 384 and spec["num_cams_x"] == 9
    assert spec["center_cam_rx_rad"] == params["center_cam_rx_rad"]
    assert spec["authors"] == ["a b", "c d"]
    assert formats.read_hci_config(p)["image_resolution_y_px"] == 384


def test_blender_euler_of_camera_looking_along_world_y():
    # A Blender camera with rotation (pi/2, 0, 0) looks along +Y with +Z up: OpenCV x = +X, y = -Z, z = +Y.
    c2w = np.eye(4)
    c2w[:3, :3] = np.array([[1, 0, 0], [0, 0, 1], [0, -1, 0]], float)
    rx, ry, rz = formats.blender_euler_xyz(c2w)
    assert (rx, ry, rz) == pytest.approx((np.pi / 2, 0.0, 0.0), abs=1e-12)


@pytest.mark.parametrize("matlab", [False, True])
def test_lf_h5_round_trip(tmp_path, matlab):
    import h5py

    lf = RNG.integers(0, 256, (2, 3, 4, 5, 3), dtype=np.uint8)
    p = tmp_path / ("lf.mat" if matlab else "lf.h5")
    formats.write_lf_h5(p, lf, matlab=matlab)
    with h5py.File(p, "r") as f:
        raw = f["LF"][()]
    # both hold MATLAB's column-major order, as BasicLFSR's transpose((4,3,2,1,0)) expects
    assert raw.shape == (3, 5, 4, 3, 2)
    np.testing.assert_array_equal(raw[2, 4, 1, 0, 1], lf[1, 0, 1, 4, 2])
    assert (p.read_bytes()[:19] == b"MATLAB 7.3 MAT-file") == matlab
    np.testing.assert_array_equal(formats.read_lf_h5(p), lf)


def test_lf_h5_in_the_old_axis_order_is_a_one_line_error(tmp_path):
    import h5py

    p = tmp_path / "old.h5"
    with h5py.File(p, "w") as f:
        f.create_dataset("LF", data=np.zeros((2, 2, 4, 5, 3), np.uint8))
    with pytest.raises(LfusdError) as e:
        formats.read_lf_h5(p)
    assert "MATLAB order" in str(e.value) and "\n" not in str(e.value)


@pytest.mark.parametrize("ext", ["flo5", "dsp5"])
def test_spring_h5_round_trip(tmp_path, ext):
    import h5py

    a = RNG.normal(size=(6, 8, 2) if ext == "flo5" else (6, 8)).astype(np.float32)
    a.flat[3] = np.nan
    p = tmp_path / f"a.{ext}"
    (formats.write_flo5 if ext == "flo5" else formats.write_dsp5)(p, a)
    with h5py.File(p, "r") as f:  # Spring's flow_IO: one dataset named 'flow' / 'disparity'
        assert list(f.keys()) == ["flow" if ext == "flo5" else "disparity"]
        np.testing.assert_array_equal(f[list(f.keys())[0]][()], a)
    np.testing.assert_array_equal((formats.read_flo5 if ext == "flo5" else formats.read_dsp5)(p), a)
    with pytest.raises(LfusdError):
        (formats.read_dsp5 if ext == "flo5" else formats.read_flo5)(p)


def test_bad_files_are_one_line_errors(tmp_path):
    for fn in (formats.read_pfm, formats.read_flo, formats.read_kitti_flow, formats.read_lf_h5):
        with pytest.raises(LfusdError) as e:
            fn(tmp_path / "missing.bin")
        assert "\n" not in str(e.value) and "does not exist" in str(e.value)
    junk = tmp_path / "junk.pfm"
    junk.write_bytes(b"hello")
    with pytest.raises(LfusdError):
        formats.read_pfm(junk)
    with pytest.raises(LfusdError):
        formats.read_flo(junk)
    with pytest.raises(LfusdError):
        formats.write_flo(tmp_path / "x.flo", np.zeros((3, 3)))

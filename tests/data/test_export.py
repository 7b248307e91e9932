"""Exports of an analytic fake dataset, read back with readers written from the format specs."""

from __future__ import annotations

import numpy as np
import pytest

from support.fake import FakeDataset
from lfusd import LfusdError
from lfusd import exports as export
from lfusd.cli import main
from support.spec_readers import read_flo_spec, read_hci_cfg_spec, read_pfm_spec, read_png_spec


@pytest.fixture(scope="module")
def ds():
    return FakeDataset(root="/data/fakescene", rows=3, cols=3, width=24, height=20, frames=(1, 2, 3))


def test_hci_export_reads_back_with_spec_readers(ds, tmp_path):
    folders = export.hci.export_hci(ds, tmp_path / "hci", frame=2, all_views=True)
    assert [f.name for f in folders] == ["fakescene_f0002"]
    sd = folders[0]
    centre = ds.rig.centre_view
    disp = read_pfm_spec(sd / "gt_disp_lowres.pfm")
    assert np.max(np.abs(disp - ds.read(2, centre, "disparity"))) < 1e-4
    np.testing.assert_array_equal(read_pfm_spec(sd / "gt_depth_lowres.pfm"), ds.read(2, centre, "depth"))
    # row-major numbering: Cam003 is row 1, column 0; Cam004 the centre of a 3x3 grid
    np.testing.assert_array_equal(read_png_spec(sd / "input_Cam004.png"), ds.read(2, centre, "rgb"))
    np.testing.assert_array_equal(read_png_spec(sd / "input_Cam003.png"), ds.read(2, (1, 0), "rgb"))
    np.testing.assert_array_equal(read_pfm_spec(sd / "gt_disp_lowres_Cam002.pfm"), ds.read(2, (0, 2), "disparity"))
    assert sorted(p.name for p in sd.glob("input_Cam*.png")) == [f"input_Cam{i:03d}.png" for i in range(9)]
    assert np.all(read_png_spec(sd / "valid_mask.png") == 255)
    cfg = read_hci_cfg_spec(sd / "parameters.cfg")
    assert (cfg["width"], cfg["height"], cfg["num_cams_x"], cfg["num_cams_y"]) == (24, 20, 3, 3)
    assert cfg["baseline_mm"] == pytest.approx(50.0)
    assert cfg["focal_length_mm"] == 36.0 and cfg["sensor_size_mm"] == 36.0
    d = ds.read(2, centre, "disparity")
    assert (cfg["disp_min"], cfg["disp_max"]) == pytest.approx((d.min(), d.max()))
    assert cfg["frustum_disp_min"] <= cfg["disp_min"] and cfg["frustum_disp_max"] >= cfg["disp_max"]
    # the rig at (0,-10,1.5) looks along +Y: Blender rotation (pi/2, 0, 0), as HCI's scenes store it
    assert (cfg["center_cam_rx_rad"], cfg["center_cam_ry_rad"], cfg["center_cam_rz_rad"]) == pytest.approx((np.pi / 2, 0, 0), abs=1e-9)
    assert (cfg["center_cam_x_m"], cfg["center_cam_y_m"], cfg["center_cam_z_m"]) == pytest.approx((0, -10, 1.5))


def test_hci_disparity_agrees_with_depth_and_views(ds, tmp_path):
    """The exported pair is self-consistent with the HCI geometry: d = f_px * b / z."""
    sd = export.hci.export_hci(ds, tmp_path / "hci", frame=1)[0]
    cfg = read_hci_cfg_spec(sd / "parameters.cfg")
    f_px = cfg["focal_length_mm"] / cfg["sensor_size_mm"] * max(cfg["width"], cfg["height"])
    depth = read_pfm_spec(sd / "gt_depth_lowres.pfm")
    disp = read_pfm_spec(sd / "gt_disp_lowres.pfm")
    np.testing.assert_allclose(disp, f_px * cfg["baseline_mm"] / 1000 / depth, rtol=1e-6)


def test_kitti_export_round_trip(ds, tmp_path):
    tr = export.kitti.export_kitti(ds, tmp_path / "kitti")
    names = sorted(p.name for p in (tr / "flow_occ").iterdir())
    assert names == ["000000_10.png", "000001_10.png"]  # frames 1->2 and 2->3; frame 3 has no next
    c = ds.rig.centre_view
    raw = read_png_spec(tr / "flow_occ" / "000001_10.png")
    flow = ds.read(2, c, "flow_fwd")
    u = (raw[..., 0].astype(float) - 2**15) / 64
    v = (raw[..., 1].astype(float) - 2**15) / 64
    assert np.all(raw[..., 2] == 1)
    assert np.max(np.abs(u - flow[..., 0])) <= 1 / 128 + 1e-6 and np.max(np.abs(v - flow[..., 1])) <= 1 / 128 + 1e-6
    d0 = read_png_spec(tr / "disp_occ_0" / "000001_10.png") / 256.0
    assert np.max(np.abs(d0 - ds.read(2, c, "disparity"))) <= 1 / 512 + 1e-6
    d1 = read_png_spec(tr / "disp_occ_1" / "000001_10.png") / 256.0
    assert np.max(np.abs(d1 - ds.read(2, c, "disparity") - ds.read(2, c, "disparity_change"))) <= 1 / 512 + 1e-6
    np.testing.assert_array_equal(read_png_spec(tr / "image_3" / "000000_11.png"), ds.read(2, (c[0], c[1] + 1), "rgb"))
    noc = read_png_spec(tr / "flow_noc" / "000001_10.png")[..., 2] > 0
    np.testing.assert_array_equal(noc, ~ds.read(2, c, "occlusion_fwd"))


def test_flo_and_pfm_exports(ds, tmp_path):
    files = export.flo.export_flo(ds, tmp_path / "flo", view=(0, 1))
    names = sorted(p.relative_to(tmp_path / "flo").as_posix() for p in files)
    assert names == ["flow_bwd/0002_00_01.flo", "flow_bwd/0003_00_01.flo", "flow_fwd/0001_00_01.flo", "flow_fwd/0002_00_01.flo"]
    np.testing.assert_array_equal(read_flo_spec(tmp_path / "flo/flow_fwd/0002_00_01.flo"), ds.read(2, (0, 1), "flow_fwd"))
    export.pfm.export_pfm(ds, tmp_path / "pfm", frame=3, all_views=True)
    np.testing.assert_array_equal(read_pfm_spec(tmp_path / "pfm/depth/0003_02_01.pfm"), ds.read(3, (2, 1), "depth"))
    assert not (tmp_path / "pfm/disparity_change/0003_02_01.pfm").exists()  # no frame 4


def test_lfmat_export(ds, tmp_path):
    """The .h5 holds LF in MATLAB's axis order [3,W,H,V,U], float32 in [0, 1] (read as BasicLFSR
    does in test_export_benchmarks.py)."""
    import h5py

    (p,) = export.lfmat.export_lfmat(ds, tmp_path / "lf", frame=1)
    with h5py.File(p, "r") as f:
        lf = f["LF"][()]
    assert lf.shape == (3, 24, 20, 3, 3) and lf.dtype == np.float32
    np.testing.assert_array_equal(np.rint(lf[:, :, :, 2, 0].T * 255).astype(np.uint8), ds.read(1, (0, 2), "rgb"))


def test_existing_target_and_bad_frame_are_one_line_errors(ds, tmp_path):
    (tmp_path / "taken").mkdir()
    for fmt in export.FORMATS:
        if export.FORMATS[fmt].resumable:  # the training cache completes its own folder (tests/data/test_cache.py)
            continue
        with pytest.raises(LfusdError) as e:
            export.export(ds, fmt, tmp_path / "taken")
        assert "already exists" in str(e.value) and "\n" not in str(e.value)
    with pytest.raises(LfusdError) as e:
        export.pfm.export_pfm(ds, tmp_path / "new", frame=99)
    assert "frame 99" in str(e.value)
    with pytest.raises(LfusdError):
        export.flo.export_flo(ds, tmp_path / "new2", view=(7, 7))


def test_cli_missing_dataset_is_one_line_error(tmp_path, capsys):
    assert main(["export", "hci", str(tmp_path / "nope"), str(tmp_path / "dest")]) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith("lfusd: error:") and "does not exist" in err and "\n" not in err


@pytest.mark.render
def test_hci_export_of_a_rendered_scene(box_dataset, tmp_path):
    """Acceptance: the HCI export of a Blender-rendered scene, read back with the spec readers,
    equals the dataset's centre-view disparity (< 1e-4) and RGB."""
    from lfusd import Dataset

    _, out = box_dataset
    assert main(["export", "hci", str(out), str(tmp_path / "hci"), "--rig", "main"]) == 0
    ds = Dataset(out, rig="main")
    t = ds.frames[0]
    (sd,) = sorted((tmp_path / "hci").iterdir())
    c = ds.rig.centre_view
    disp = ds.read(t, c, "disparity")
    got = read_pfm_spec(sd / "gt_disp_lowres.pfm")
    fin = np.isfinite(disp)
    assert fin.mean() > 0.5 and np.max(np.abs(got[fin] - disp[fin])) < 1e-4
    np.testing.assert_array_equal(np.isfinite(got), fin)
    idx = c[0] * ds.rig.cols + c[1]
    np.testing.assert_array_equal(read_png_spec(sd / f"input_Cam{idx:03d}.png"), ds.read(t, c, "rgb"))
    np.testing.assert_array_equal(read_png_spec(sd / "input_Cam000.png"), ds.read(t, (0, 0), "rgb"))
    cfg = read_hci_cfg_spec(sd / "parameters.cfg")
    assert (cfg["width"], cfg["height"], cfg["num_cams_x"]) == (ds.rig.width, ds.rig.height, ds.rig.cols)
    pose = ds.cam_to_world(t, c)
    assert (cfg["center_cam_x_m"], cfg["center_cam_y_m"], cfg["center_cam_z_m"]) == pytest.approx(tuple(pose[:3, 3]))


def test_the_facade_export_is_the_registry_dispatch_and_the_cli_offers_every_registered_format():
    import argparse

    import lfusd
    from lfusd.commands import export as command

    assert lfusd.export is export.export  # the subpackage is lfusd.exports, so lfusd.export stays the function
    parser = argparse.ArgumentParser()
    command.register(parser.add_subparsers())
    sub = next(a for a in parser._actions if isinstance(a, argparse._SubParsersAction)).choices["export"]
    fmt = next(a for a in sub._actions if a.dest == "format")
    assert list(fmt.choices) == list(export.FORMATS) == ["hci", "kitti", "spring", "flo", "pfm", "lfmat", "hf", "webdataset", "cache"]
    flags = {s for a in sub._actions for s in a.option_strings}
    assert {o.flag for f in export.FORMATS.values() for o in f.options} <= flags

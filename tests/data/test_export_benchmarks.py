"""Exports read back with each benchmark's own reading code, re-implemented here from its source.

- HCI: python-tools ``file_io.read_pfm`` / ``read_parameters`` and the evaluation toolkit's
  ``BaseScene.disp2depth`` / ``depth2disp`` / ``compute_offset`` / ``get_center_cam``.
- KITTI: the 16-bit PNG encodings of the devkit; ``noc`` masks (the devkit readme: correspondence inside the image) against geometry computed here
  in closed form (the analytic scene) or by ray casting (a tiny render).
- Spring: ``flow_IO.readFlo5Flow`` / ``readDsp5Disp`` and its data loaders (paths, ``[::2, ::2]``,
  the left camera's negated disparity).
- BasicLFSR / DistgASR: ``Generate_Data_for_Training.py`` (h5py, ``transpose((4, 3, 2, 1, 0))``,
  ``rgb2ycbcr`` on [0, 1]) and MATLAB's reversed HDF5 dimensions for ``load`` of a v7.3 .mat.
"""

from __future__ import annotations

import configparser
import os
from glob import glob

import numpy as np
import pytest

from support.fake import S, V, ZB, ZF0, FakeDataset
from support.spec_readers import read_png_spec
from lfusd import LfusdError
from lfusd import exports as export
from lfusd.truth import visibility

# ---- HCI ---------------------------------------------------------------------------------------


def hci_read_pfm(path) -> np.ndarray:
    """python-tools file_io.read_pfm: header lines, np.fromfile, reshape, flipud, times |scale|."""
    with open(path, "rb") as f:
        assert f.readline().rstrip() == b"Pf"
        width, height = (int(x) for x in f.readline().split())
        scale = float(f.readline())
        data = np.fromfile(f, ("<" if scale < 0 else ">") + "f")
    return np.flipud(data.reshape(height, width)) * abs(scale)


class HciScene:
    """The toolkit's BaseScene: what it reads from parameters.cfg and its conversions."""

    def __init__(self, folder):
        p = configparser.ConfigParser()
        p.read(os.path.join(folder, "parameters.cfg"))
        self.width = int(p.get("intrinsics", "image_resolution_x_px"))
        self.height = int(p.get("intrinsics", "image_resolution_y_px"))
        self.focal_length_mm = float(p.get("intrinsics", "focal_length_mm"))
        self.sensor_mm = float(p.get("intrinsics", "sensor_size_mm"))
        self.num_cams_x = int(p.get("extrinsics", "num_cams_x"))
        self.num_cams_y = int(p.get("extrinsics", "num_cams_y"))
        self.baseline_mm = float(p.get("extrinsics", "baseline_mm"))
        self.focus_dist_m = float(p.get("extrinsics", "focus_distance_m"))

    def get_center_cam(self):
        return int(self.num_cams_x * self.num_cams_y / 2.0)

    def compute_offset(self):
        return self.baseline_mm * self.focal_length_mm / self.focus_dist_m / 1000.0 / self.sensor_mm * max(self.width, self.height)

    def disp2depth(self, disp_map):
        q = self.baseline_mm * self.focal_length_mm * max(self.width, self.height)
        return 1.0 / ((1000.0 * self.sensor_mm) * disp_map / q + (1.0 / self.focus_dist_m))

    def depth2disp(self, depth_map):
        f = (self.baseline_mm / 1000.0) * self.focal_length_mm * max(self.width, self.height)
        return (f * self.focus_dist_m / depth_map - f) / self.focus_dist_m / self.sensor_mm


@pytest.mark.parametrize("rows,cols,width,height", [(3, 3, 24, 20), (2, 2, 16, 24)], ids=["landscape-3x3", "portrait-2x2"])
def test_hci_toolkit_formulas_give_lfusd_depth_and_disparity(tmp_path, rows, cols, width, height):
    ds = FakeDataset(rows=rows, cols=cols, width=width, height=height, frames=(1,))
    (sd,) = export.hci.export_hci(ds, tmp_path / "hci")
    scene = HciScene(sd)
    # the toolkit's centre camera is int(nx*ny/2), row-major: (1,1) of 3x3, (1,0) of 2x2
    view = divmod(scene.get_center_cam(), cols)
    gt_disp = hci_read_pfm(sd / "gt_disp_lowres.pfm")
    gt_depth = hci_read_pfm(sd / "gt_depth_lowres.pfm")
    depth = ds.read(1, view, "depth").astype(np.float64)
    # geometry, independent of lfusd: disparity is the pixel shift per baseline, f_px * b / z
    # with f_px = K[0,0] of the rendered views
    f_px = ds.intrinsics(view)[0, 0]
    np.testing.assert_allclose(gt_disp, f_px * ds.baseline / depth, rtol=1e-6)
    np.testing.assert_allclose(gt_depth, depth, rtol=1e-7)
    # the toolkit's own conversions reproduce them, on a portrait rig too (sensor of the larger side)
    assert scene.sensor_mm == pytest.approx(36.0 * max(width, height) / width)
    np.testing.assert_allclose(scene.disp2depth(gt_disp), depth, rtol=1e-6)
    np.testing.assert_allclose(scene.depth2disp(gt_depth), gt_disp, rtol=1e-6)
    assert np.isfinite(scene.focus_dist_m) and scene.focus_dist_m > 0
    assert abs(scene.compute_offset()) < 1e-9  # an unshifted rig: the disparity = 0 plane is at infinity
    print(f"HCI {width}x{height}: compared {depth.size} px of depth and disparity")


@pytest.mark.parametrize("k", [1, -2])
def test_hci_sensor_shift_gives_signed_disparity_the_toolkit_reads_back(tmp_path, k):
    """`lfusd export hci --shift k`: HCI's sensor shift as an exact integer crop. Each exported view
    (r, c) at grid offset (sx, sy) is the rendered one moved by (k*sx, k*sy) px, so a centre point
    at disparity d is at disparity d - k; the toolkit's own conversions (disp2depth with the
    written focus distance, compute_offset) give the rendered depth and k back."""
    ds = FakeDataset(rows=3, cols=3, width=24, height=20, frames=(1,))
    (sd,) = export.hci.export_hci(ds, tmp_path / "hci", shift=str(k))
    scene = HciScene(sd)
    m = abs(k)  # crop per side: |k| * max|offset| (offsets -1, 0, 1)
    assert (scene.width, scene.height) == (24 - 2 * m, 20 - 2 * m)
    c = ds.rig.centre_view
    win = np.s_[m : 20 - m, m : 24 - m]
    gt_disp = hci_read_pfm(sd / "gt_disp_lowres.pfm")
    np.testing.assert_allclose(gt_disp, ds.read(1, c, "disparity")[win] - k, rtol=0, atol=1e-5)
    np.testing.assert_array_equal(hci_read_pfm(sd / "gt_depth_lowres.pfm"), ds.read(1, c, "depth")[win])
    # geometry: disparity d - k = f_px * b * (1/z - 1/F), with f_px of the rendered views and F written
    f_px, depth = ds.intrinsics(c)[0, 0], ds.read(1, c, "depth")[win].astype(np.float64)
    np.testing.assert_allclose(gt_disp, f_px * ds.baseline * (1 / depth - 1 / scene.focus_dist_m), rtol=0, atol=1e-4)
    np.testing.assert_allclose(scene.disp2depth(gt_disp), depth, rtol=1e-5)
    assert scene.compute_offset() == pytest.approx(k, rel=1e-9)
    # the images: view at offset (sx, sy) shifted by k*(sx, sy): I'(y, x) = I(y + m - k*sy, x + m - k*sx)
    for idx in range(9):
        r, col = divmod(idx, 3)
        sx, sy = (int(o) for o in ds.rig.offsets((r, col)))
        src = ds.read(1, (r, col), "rgb")
        want = src[m - k * sy : m - k * sy + 20 - 2 * m, m - k * sx : m - k * sx + 24 - 2 * m]
        np.testing.assert_array_equal(read_png_spec(sd / f"input_Cam{idx:03d}.png"), want)


def test_hci_shift_must_be_whole_pixels(tmp_path):
    ds = FakeDataset(rows=3, cols=3, width=12, height=10, frames=(1,))
    with pytest.raises(LfusdError, match="whole number"):
        export.hci.export_hci(ds, tmp_path / "hci", shift="0.5")


def test_hci_read_lightfield_indexing(tmp_path):
    """python-tools read_lightfield: sorted input_Cam*.png, view idx at [idx / nx, idx % ny]."""
    ds = FakeDataset(rows=3, cols=3, width=12, height=10, frames=(1,))
    (sd,) = export.hci.export_hci(ds, tmp_path / "hci")
    views = sorted(f for f in os.listdir(sd) if f.startswith("input_") and f.endswith(".png"))
    for idx, name in enumerate(views):
        np.testing.assert_array_equal(read_png_spec(sd / name), ds.read(1, (idx // 3, idx % 3), "rgb"))


# ---- KITTI: noc masks against closed-form visibility -------------------------------------------


def _fake_truth(ds, t: float, u, v, t_seen: float):
    """Closed-form scene of support.fake: the rig-frame point seen at centre-view pixel (u, v) at
    frame t_seen, moved to frame t (the box moves by V per frame, the wall is static), and
    whether it is on the box."""
    k = ds.rig.intrinsics()
    f, cx, cy = k[0, 0], k[0, 2], k[1, 2]
    c0 = np.array([0.0, 0.0, ZF0]) + (t_seen - ds.frames[0]) * V
    dx, dy = (u - cx) / f, (v - cy) / f
    on_box = (np.abs(dx * c0[2] - c0[0]) <= S) & (np.abs(dy * c0[2] - c0[1]) <= S)
    z = np.where(on_box, c0[2], ZB)
    p = np.stack([dx * z, dy * z, z], -1) + np.where(on_box[..., None], (t - t_seen) * V, 0.0)
    return p, on_box


def _right_view_visibility(ds, p, on_box, t: float, b_right: float):
    """For points p (rig frame) at frame t: (x, y) in the right view, inside, hidden by the box,
    and 'ambiguous' (within 1 px of the box's silhouette there, where pixels cannot decide)."""
    k = ds.rig.intrinsics()
    f, cx, cy = k[0, 0], k[0, 2], k[1, 2]
    W, H = ds.rig.width, ds.rig.height
    o = np.array([b_right, 0.0, 0.0])
    x = f * (p[..., 0] - o[0]) / p[..., 2] + cx
    y = f * p[..., 1] / p[..., 2] + cy
    inside = (x >= -0.5) & (x <= W - 0.5) & (y >= -0.5) & (y <= H - 0.5)
    c = np.array([0.0, 0.0, ZF0]) + (t - ds.frames[0]) * V
    s = (c[2] - o[2]) / (p[..., 2] - o[2])  # where the segment from the camera to p crosses the box's plane
    qx, qy = o[0] + s * (p[..., 0] - o[0]), o[1] + s * (p[..., 1] - o[1])
    hidden = ~on_box & (np.abs(qx - c[0]) <= S) & (np.abs(qy - c[1]) <= S)
    xe = f * (c[0] + np.array([-S, S]) - o[0]) / c[2] + cx  # box silhouette edges in the right view
    ye = f * (c[1] + np.array([-S, S])) / c[2] + cy
    in_x = (x > xe[0] - 1) & (x < xe[1] + 1)
    in_y = (y > ye[0] - 1) & (y < ye[1] + 1)
    near = (in_y & (np.min(np.abs(x[..., None] - xe), -1) < 1)) | (in_x & (np.min(np.abs(y[..., None] - ye), -1) < 1))
    return inside, hidden, near


def test_kitti_noc_keeps_points_whose_correspondence_is_inside_the_image(tmp_path):
    """The devkit readme: 'noc' = regions whose matching correspondence is inside the image domain
    (a point hidden in the other image is still noc)."""
    ds = FakeDataset(rows=3, cols=3, width=48, height=40, frames=(1, 2), baseline=0.5)
    tr = export.kitti.export_kitti(ds, tmp_path / "kitti")
    name = "000000_10.png"

    def disp_mask(sub):
        raw = read_png_spec(tr / sub / name)
        return raw > 0, raw / 256.0

    occ0, d_occ0 = disp_mask("disp_occ_0")
    noc0, d_noc0 = disp_mask("disp_noc_0")
    occ1, _ = disp_mask("disp_occ_1")
    noc1, _ = disp_mask("disp_noc_1")
    flow_noc = read_png_spec(tr / "flow_noc" / name)[..., 2] > 0
    v, u = np.mgrid[0:40, 0:48].astype(np.float64)
    b = ds.baseline  # the right view sits one baseline to the right of the centre view
    W, H = ds.rig.width, ds.rig.height

    def landing(p, b_cam):
        k = ds.rig.intrinsics()
        return k[0, 0] * (p[..., 0] - b_cam) / p[..., 2] + k[0, 2], k[1, 1] * p[..., 1] / p[..., 2] + k[1, 2]

    def inside_and_sure(x, y):
        inside = (x >= -0.5) & (x < W - 0.5) & (y >= -0.5) & (y < H - 0.5)
        edge = np.minimum.reduce([np.abs(x + 0.5), np.abs(x - (W - 0.5)), np.abs(y + 0.5), np.abs(y - (H - 0.5))])
        return inside, edge > 1e-3  # a landing point on the border itself is float rounding's call

    # disparity at t: the correspondence in image_3 at t
    p, on_box = _fake_truth(ds, 1, u, v, 1)
    inside, sure = inside_and_sure(*landing(p, b))
    _, hidden, _ = _right_view_visibility(ds, p, on_box, 1, b)
    assert occ0.all()  # every pixel sees a surface
    n_out, n_hid = int((~inside & sure).sum()), int((hidden & inside).sum())
    assert n_out > 0 and n_hid > 0, (n_out, n_hid)
    np.testing.assert_array_equal(noc0[sure], inside[sure])
    assert noc0[hidden & inside].all(), "a point hidden in image_3 but inside it is noc by the readme"
    assert np.max(np.abs(d_noc0[noc0] - ds.read(1, (1, 1), "disparity")[noc0])) <= 1 / 512 + 1e-6
    print(f"disp_noc_0: compared {int(sure.sum())} px; excluded {n_out} outside image_3; kept {n_hid} hidden in it")

    # disparity at t+1 of the point seen at t: its correspondences in image_2 and image_3 at t+1
    np.testing.assert_array_equal(flow_noc, ds.read(1, (1, 1), "valid_fwd") & ~ds.read(1, (1, 1), "occlusion_fwd"))
    p1, on_box = _fake_truth(ds, 2, u, v, 1)
    in_l, sure_l = inside_and_sure(*landing(p1, 0.0))
    in_r, sure_r = inside_and_sure(*landing(p1, b))
    sure1 = sure_l & sure_r
    expect1 = occ1 & in_l & in_r
    assert occ1.all() and (~expect1 & sure1).sum() > 0
    np.testing.assert_array_equal(noc1[sure1], expect1[sure1])
    print(f"disp_noc_1: compared {int(sure1.sum())} px; {int((~expect1 & sure1).sum())} excluded")


def test_visible_in_view_on_a_slanted_plane_and_at_silhouettes():
    """A plane whose disparity is affine in (u, v) is visible wherever the point lands (slopes are
    extrapolated); a nearer surface over the landing pixels hides it; a point landing next to a
    pixel that sees something farther is on a silhouette and visible."""
    v, u = np.mgrid[0:20, 0:30].astype(np.float64)
    plane = 3.0 + 0.15 * u + 0.08 * v
    rng = np.random.default_rng(0)
    x, y = rng.uniform(1, 28, 500), rng.uniform(1, 18, 500)
    d = 3.0 + 0.15 * x + 0.08 * y
    assert visibility.visible_in_view(x, y, d, plane).all()
    assert not visibility.visible_in_view(x, y, d * 0.99, plane).any()  # a point 1 % farther: the plane hides it
    assert visibility.visible_in_view(x, y, d * 1.01, plane).all()  # 1 % nearer: in front of the plane
    occluder = plane.copy()
    occluder[:, 10:20] = 20.0
    xs = np.array([14.0, 14.4, 8.6, 21.0])
    vis = visibility.visible_in_view(xs, np.full(4, 5.0), 3.0 + 0.15 * xs + 0.4, occluder)
    assert vis.tolist() == [False, False, True, True]
    assert not visibility.visible_in_view(np.array([-0.6, 29.6]), np.array([5.0, 5.0]), np.array([5.0, 5.0]), plane).any()


@pytest.mark.render
def test_kitti_noc_on_a_rendered_scene(tmp_path):
    """A tiny 1x2 render of moving boxes over a ground plane: disp_noc_0 against ray casting."""
    from support.analytic import cast, hit_box, hit_plane_z0, pixel_rays, project
    from support.scenes import GROUND_HALF, movers_world, write_motion_stage

    from lfusd.camera import RigSpec
    from lfusd.cli import main

    rig = RigSpec(name="main", rows=1, cols=2, width=48, height=32, baseline=1.0, at=(0.3, -5.0, 1.8), look_at=(0.0, 0.5, 0.6))
    stage = tmp_path / "movers.usda"
    write_motion_stage(stage, rig, frames=2)
    out = tmp_path / "out"
    assert main(["render-video", str(stage), "-o", str(out), "--samples", "1", "--quiet", "--device", "cpu", "--workers", "1"]) == 0
    assert main(["export", "kitti", str(out), str(tmp_path / "kitti")]) == 0
    assert main(["export", "spring", str(out), str(tmp_path / "spring")]) == 0
    assert (tmp_path / "spring/train/out/flow_FW_right/flow_FW_right_0001.flo5").is_file()
    raw = read_png_spec(tmp_path / "kitti/training/disp_noc_0/000000_10.png")
    noc = raw > 0
    occ = read_png_spec(tmp_path / "kitti/training/disp_occ_0/000000_10.png") > 0

    K = rig.intrinsics()
    boxes = movers_world(1)
    left, right = rig.cam_to_world((0, 0)), rig.cam_to_world((0, 1))
    depth, _ = cast(K, left, rig.width, rig.height, boxes, GROUND_HALF)
    o, dirs = pixel_rays(K, left, rig.width, rig.height)
    fin = np.isfinite(depth)
    P = o + depth[..., None] * dirs
    xy = np.full(depth.shape + (2,), np.nan)
    xy[fin] = project(K, right, P[fin])
    z_right = np.full(depth.shape, np.nan)
    z_right[fin] = (P[fin] - right[:3, 3]) @ right[:3, 2]  # the point's depth in the right camera

    def first_hit(uv):
        """(ray parameter = depth, surface index) of the first surface along right-view rays through uv."""
        pix = np.concatenate([uv, np.ones((len(uv), 1))], axis=1)
        d = (pix @ np.linalg.inv(K).T) @ right[:3, :3].T
        ts = np.stack([hit_plane_z0(right[:3, 3], d, GROUND_HALF)] + [hit_box(right[:3, 3], d, m, s) for m, s in boxes.values()])
        return ts.min(axis=0), np.argmin(ts, axis=0)

    idx = np.flatnonzero(fin)
    q = xy.reshape(-1, 2)[idx]
    W, H = rig.width, rig.height
    inside = (q[:, 0] >= -0.5) & (q[:, 0] <= W - 0.5) & (q[:, 1] >= -0.5) & (q[:, 1] <= H - 0.5)
    t_hit, _ = first_hit(q)
    visible = inside & (t_hit >= z_right.ravel()[idx] * (1 - 1e-4))
    # the devkit readme's noc: the correspondence inside image_3, hidden or not; undecidable within
    # 0.01 px of the image border (the rendered depth's rounding)
    border = np.minimum(np.abs(q[:, 0] + 0.5), np.abs(q[:, 0] - (W - 0.5))) < 0.01
    sure = ~border
    got = noc.ravel()[idx]
    n_out, n_hid = int((~inside & sure).sum()), int((inside & ~visible & sure).sum())
    assert n_out > 0 and n_hid > 0, (n_out, n_hid)
    assert occ.ravel()[idx].all()
    np.testing.assert_array_equal(got[sure], inside[sure])
    print(f"rendered disp_noc_0: compared {int(sure.sum())} px; excluded {n_out} outside image_3, kept {n_hid} hidden in it")


# ---- Spring ------------------------------------------------------------------------------------


def spring_read(path, key):
    """flow_IO.readFlo5Flow / readDsp5Disp: dataset 'flow' / 'disparity' of an HDF5 file."""
    import h5py

    with h5py.File(path, "r") as f:
        assert key in f.keys()
        return f[key][()]


def test_spring_export_reads_with_springs_loaders(tmp_path):
    ds = FakeDataset(root="/data/fakescene", rows=3, cols=3, width=48, height=40, frames=(4, 5, 6), baseline=0.25)
    sd = export.spring.export_spring(ds, tmp_path / "spring")
    seq_root = tmp_path / "spring" / "train"
    assert sd == seq_root / "fakescene"
    views = {"left": (1, 1), "right": (1, 2)}
    n = 0
    for scene in sorted(os.listdir(seq_root)):
        for cam in ["left", "right"]:
            images = sorted(glob(os.path.join(seq_root, scene, f"frame_{cam}", "*.png")))
            assert len(images) == 3
            pairs = [(f, "FW") for f in range(1, len(images))] + [(f, "BW") for f in reversed(range(2, len(images) + 1))]
            for frame, direction in pairs:  # SpringFlowDataset
                t = 3 + frame  # frames 4, 5, 6 are Spring's 1, 2, 3
                flow = spring_read(os.path.join(seq_root, scene, f"flow_{direction}_{cam}", f"flow_{direction}_{cam}_{frame:04d}.flo5"), "flow")
                assert flow.shape == (80, 96, 2)  # twice the image resolution
                flow = flow[::2, ::2]
                np.testing.assert_array_equal(flow, ds.read(t, views[cam], "flow_fwd" if direction == "FW" else "flow_bwd"))
                n += flow[..., 0].size
            for frame in range(1, len(images) + 1):  # SpringStereoDataset
                t = 3 + frame
                img1 = read_png_spec(os.path.join(seq_root, scene, f"frame_{cam}", f"frame_{cam}_{frame:04d}.png"))
                np.testing.assert_array_equal(img1, ds.read(t, views[cam], "rgb"))
                disp = spring_read(os.path.join(seq_root, scene, f"disp1_{cam}", f"disp1_{cam}_{frame:04d}.dsp5"), "disparity")[::2, ::2]
                np.testing.assert_array_equal(disp, ds.read(t, views[cam], "disparity"))
                if frame < len(images):  # SpringSceneFlowDataset, forward
                    d2 = spring_read(os.path.join(seq_root, scene, f"disp2_FW_{cam}", f"disp2_FW_{cam}_{frame:04d}.dsp5"), "disparity")[::2, ::2]
                    want = ds.read(t, views[cam], "disparity") + ds.read(t, views[cam], "disparity_change")
                    np.testing.assert_allclose(d2, want, rtol=1e-6)
    # the sign: Spring's loader negates the left camera's disparity into the x displacement to the
    # right image; on the wall (4 px here, rows clear of the box) the right image repeats the left
    left = read_png_spec(sd / "frame_left" / "frame_left_0001.png").astype(int)
    right = read_png_spec(sd / "frame_right" / "frame_right_0001.png").astype(int)
    disp = -spring_read(sd / "disp1_left" / "disp1_left_0001.dsp5", "disparity")[::2, ::2]
    rows = np.r_[0:8, 32:40]
    shift = np.rint(disp[rows]).astype(int)
    assert np.all(shift == -4) and np.abs(disp[rows] + 4).max() < 1e-5
    np.testing.assert_array_equal(left[rows, 4:], right[rows, :-4])
    print(f"Spring: compared {n} flow px and {rows.size * 44} px of the stereo shift")


def test_spring_marks_unknown_as_nan(tmp_path):
    ds = FakeDataset(rows=1, cols=2, width=16, height=12, frames=(1, 2))
    sd = export.spring.export_spring(ds, tmp_path / "s")
    assert not (sd / "flow_FW_left" / "flow_FW_left_0002.flo5").exists()  # no frame 3
    assert not (sd / "flow_BW_left" / "flow_BW_left_0001.flo5").exists()  # no frame 0
    d = spring_read(sd / "disp1_left" / "disp1_left_0001.dsp5", "disparity")
    assert d.dtype == np.float32 and np.isfinite(d).all()


# ---- BasicLFSR / DistgASR ----------------------------------------------------------------------


def basiclfsr_rgb2ycbcr(x):
    """BasicLFSR utils.rgb2ycbcr (expects RGB in [0, 1])."""
    y = np.zeros(x.shape, dtype="double")
    y[:, :, 0] = 65.481 * x[:, :, 0] + 128.553 * x[:, :, 1] + 24.966 * x[:, :, 2] + 16.0
    y[:, :, 1] = -37.797 * x[:, :, 0] - 74.203 * x[:, :, 1] + 112.000 * x[:, :, 2] + 128.0
    y[:, :, 2] = 112.000 * x[:, :, 0] - 93.786 * x[:, :, 1] - 18.214 * x[:, :, 2] + 128.0
    return y / 255.0


@pytest.mark.parametrize("matlab", [False, True], ids=["h5", "mat"])
def test_lfmat_reads_with_basiclfsr_preparation(tmp_path, matlab):
    import h5py

    ds = FakeDataset(rows=3, cols=3, width=24, height=20, frames=(1,))
    (p,) = export.lfmat.export_lfmat(ds, tmp_path / "lf", matlab=matlab)
    assert p.suffix == (".mat" if matlab else ".h5")
    # Generate_Data_for_Training.py / _Test.py
    data = h5py.File(p, "r")
    LF = np.array(data[("LF")]).transpose((4, 3, 2, 1, 0))
    (U, V, _, _, _) = LF.shape
    angRes = 3
    LF = LF[(U - angRes) // 2 : (U + angRes) // 2, (V - angRes) // 2 : (V + angRes) // 2, :, :, 0:3]
    LF = LF.astype("double")
    assert LF.shape == (3, 3, 20, 24, 3)
    assert 0.0 <= LF.min() and LF.max() <= 1.0
    for u in range(3):
        for v in range(3):
            np.testing.assert_array_equal(np.rint(LF[u, v] * 255).astype(np.uint8), ds.read(1, (u, v), "rgb"))
            y = basiclfsr_rgb2ycbcr(LF[u, v])[:, :, 0]
            assert 16 / 255 - 1e-9 <= y.min() and y.max() <= 235 / 255 + 1e-9  # their Y range, so inputs were in [0, 1]
    if matlab:  # MATLAB's load sees an HDF5 dataset with its dimensions reversed
        assert p.read_bytes()[:19] == b"MATLAB 7.3 MAT-file"
        assert tuple(reversed(data["LF"].shape)) == (3, 3, 20, 24, 3)
        assert data["LF"].attrs["MATLAB_class"] == b"single"
    data.close()
    print(f"BasicLFSR ({p.suffix}): compared {LF[..., 0].size} px")

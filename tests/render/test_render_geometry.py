"""Rendered ground truth against closed-form geometry (tiny Blender renders, one session fixture)."""

from __future__ import annotations

import json
import subprocess
import sys

import numpy as np

from lfusd.keys import KEYS
import pytest
from support.analytic import cast, pixel_rays, project
from support.scenes import BOXES, GROUND_HALF, PLANE_RIG, SPHERE_RIG, boxes_world

from lfusd import Dataset
from lfusd.author.stage import open_stage

pytestmark = pytest.mark.render


def _interior(mask: np.ndarray) -> np.ndarray:
    """Pixels whose 4-neighbours share the same label (no silhouette edge through them)."""
    m = mask.copy()
    m[1:, :] &= mask[:-1, :]
    m[:-1, :] &= mask[1:, :]
    m[:, 1:] &= mask[:, :-1]
    m[:, :-1] &= mask[:, 1:]
    return m


@pytest.fixture(scope="module")
def plane(box_dataset):
    return Dataset(box_dataset[1], rig="main")


@pytest.fixture(scope="module")
def dome(box_dataset):
    return Dataset(box_dataset[1], rig="dome")


def test_box_poses_in_stage_match_the_analytic_matrices(box_dataset, plane):
    stage = open_stage(box_dataset[0])
    from pxr import Usd, UsdGeom

    for path, (m, _) in boxes_world().items():
        usd = np.array(UsdGeom.Xformable(stage.GetPrimAtPath(path)).ComputeLocalToWorldTransform(Usd.TimeCode(1))).T
        np.testing.assert_allclose(usd, m, atol=1e-6)
    poses = {o.prim_path: o.poses[1] for o in plane.objects.values()}
    for path, (m, _) in boxes_world().items():
        np.testing.assert_allclose(poses[path], m, atol=1e-6)


def analytic_views(ds):
    """Per view of frame 1: (view, closed-form planar depth, instance id of the analytic hit)."""
    w, h = ds.resolution
    by_label = {o.prim_path: o.instance_id for o in ds.objects.values()}
    names = {"": 0, "ground": by_label["/World/Ground"], **{p: by_label[p] for p in boxes_world()}}
    for view in ds.views:
        depth_ref, hit = cast(ds.intrinsics(view), ds.cam_to_world(1, view), w, h, boxes_world(), GROUND_HALF)
        yield view, depth_ref, np.vectorize(names.get)(hit).astype(np.int32)


@pytest.mark.parametrize("rig", ["main", "dome"])
def test_depth_equals_closed_form_ray_casts(box_dataset, rig):
    ds = Dataset(box_dataset[1], rig=rig)
    w, h = ds.resolution
    checked = 0
    for view, depth_ref, ids_ref in analytic_views(ds):
        depth = ds.read(1, view, "depth")
        inst = ds.read(1, view, "instance")
        # Silhouettes may flip where a pixel centre grazes an edge; demand near-total agreement.
        assert (inst != ids_ref).mean() < 0.01, f"view {view}: instance ids disagree on {(inst != ids_ref).mean():.2%}"
        sel = _interior(ids_ref == inst) & (ids_ref > 0)
        rel = np.abs(depth[sel] - depth_ref[sel]) / depth_ref[sel]
        assert rel.max() < 1e-4, f"view {view}: relative depth error {rel.max():.2e}"
        assert np.all(np.isinf(depth[(ids_ref == 0) & (inst == 0)]))
        checked += sel.sum()
    assert checked > 0.5 * len(ds.views) * w * h


@pytest.mark.parametrize("rig", ["main", "dome"])
def test_depth_euclidean_equals_closed_form_ray_lengths(box_dataset, rig):
    """depth_euclidean is the distance from the camera centre to the analytic hit along the pixel's ray."""
    ds = Dataset(box_dataset[1], rig=rig)
    w, h = ds.resolution
    checked = 0
    for view, depth_ref, ids_ref in analytic_views(ds):
        _, dirs = pixel_rays(ds.intrinsics(view), ds.cam_to_world(1, view), w, h)
        with np.errstate(invalid="ignore"):
            length_ref = np.linalg.norm(depth_ref[..., None] * dirs, axis=-1)  # |hit - origin|
        got = ds.read(1, view, "depth_euclidean")
        assert got.dtype == np.float32 and got.shape == (h, w)
        sel = _interior(ids_ref == ds.read(1, view, "instance")) & (ids_ref > 0)
        rel = np.abs(got[sel] - length_ref[sel]) / length_ref[sel]
        assert rel.max() < 1e-4, f"view {view}: relative ray-length error {rel.max():.2e}"
        assert np.all(got[sel] > ds.read(1, view, "depth")[sel] * (1 - 1e-6))
        assert np.all(np.isinf(got[(ids_ref == 0) & (ds.read(1, view, "instance") == 0)]))
        checked += sel.sum()
    assert checked > 0.5 * len(ds.views) * w * h


@pytest.mark.parametrize("rig", ["main", "dome"])
def test_position_pass_reprojects_onto_pixel_centres(box_dataset, rig):
    ds = Dataset(box_dataset[1], rig=rig)
    w, h = ds.resolution
    v, u = np.mgrid[0:h, 0:w]
    for view in ds.views:
        pos = ds.read(1, view, "position")
        ok = np.isfinite(pos).all(axis=-1)
        uv = project(ds.intrinsics(view), ds.cam_to_world(1, view), pos[ok])
        err = np.hypot(uv[:, 0] - u[ok], uv[:, 1] - v[ok])
        assert err.max() < 0.01, f"view {view}: reprojection error {err.max():.4f} px"
        # The data render's single sample sits on the pixel centre (Cycles' own offset compensated).
        assert np.median(err) < 1e-4, f"view {view}: median sample offset {np.median(err):.2e} px"
        # depth is the camera-frame z of the same point
        w2c = np.linalg.inv(ds.cam_to_world(1, view))
        z = pos[ok] @ w2c[2, :3] + w2c[2, 3]
        np.testing.assert_allclose(ds.read(1, view, "depth")[ok], z, rtol=1e-4)


def test_disparity_shift_between_views_follows_the_convention(plane):
    """A surface point seen in view (r, c) lies, in the centre view, at its pixel plus d * (sx, sy)."""
    ds = plane
    centre = ds.rig.centre_view
    Kc, Tc = ds.intrinsics(centre), ds.cam_to_world(1, centre)
    w, h = ds.resolution
    v, u = np.mgrid[0:h, 0:w]
    for view in ds.views:
        sx, sy = ds.rig.offsets(view)
        assert (sx, sy) == (view[1] - centre[1], view[0] - centre[0])  # uniform grid
        pos = ds.read(1, view, "position")
        ok = np.isfinite(pos).all(axis=-1)
        uv_c = project(Kc, Tc, pos[ok])
        z_c = (pos[ok] @ np.linalg.inv(Tc)[2, :3]) + np.linalg.inv(Tc)[2, 3]
        d = ds.rig.focal_px * ds.baseline / z_c
        pred_u, pred_v = uv_c[:, 0] - d * sx, uv_c[:, 1] - d * sy
        err = np.hypot(pred_u - u[ok], pred_v - v[ok])
        assert err.max() < 0.01, f"view {view}: {err.max():.4f} px"
    # The stored disparity key is f * b / z of the centre view's own depth.
    dc, zc = ds.read(1, centre, "disparity"), ds.read(1, centre, "depth")
    fin = np.isfinite(zc)
    np.testing.assert_allclose(dc[fin], ds.rig.focal_px * ds.baseline / zc[fin], rtol=1e-6)
    assert np.all(dc[~fin] == 0)


def test_normals_are_unit_and_face_the_analytic_planes(plane):
    ds = plane
    view = ds.rig.centre_view
    n = ds.read(1, view, "normal")
    inst = ds.read(1, view, "instance")
    ground = next(i for i, o in ds.objects.items() if o.prim_path == "/World/Ground")
    ok = np.isfinite(n).all(axis=-1)
    # normals are stored as float16: each component carries at most the storage's rounding error
    e = KEYS["normal"].storage.error
    np.testing.assert_allclose(np.linalg.norm(n[ok], axis=-1), 1.0, atol=1e-4 + 2 * e)
    g = _interior(inst == ground)
    np.testing.assert_allclose(n[g], np.broadcast_to([0, 0, 1], n[g].shape), atol=1e-5 + e)
    # Box normals are one of the six face normals of the analytic box.
    for path, (m, _) in boxes_world().items():
        bid = next(i for i, o in ds.objects.items() if o.prim_path == path)
        sel = _interior(inst == bid)
        faces = np.concatenate([m[:3, :3].T, -m[:3, :3].T])  # rows: +-x, +-y, +-z axes
        best = (n[sel] @ faces.T).max(axis=1)
        np.testing.assert_allclose(best, 1.0, atol=1e-4 + 2 * e)


def test_segmentation_maps_to_prims_and_labels(plane):
    ds = plane
    labels = {f"/World/{k}": v[3] for k, v in BOXES.items()} | {"/World/Ground": "ground"}
    assert {o.prim_path: o.label for o in ds.objects.values()} == labels
    assert ds.classes[0] == ""
    for view in ds.views:
        depth_ref, hit = cast(ds.intrinsics(view), ds.cam_to_world(1, view), *ds.resolution, boxes_world(), GROUND_HALF)
        hit = np.where(hit == "ground", "/World/Ground", hit)
        inst = ds.read(1, view, "instance")
        sem = ds.read(1, view, "semantic")
        for path, label in labels.items():
            mine = _interior(hit == path)  # where the analytic hit is unambiguous
            assert mine.sum() > 0 or path != "/World/Ground"
            ids = np.unique(inst[mine])
            assert len(ids) <= 1
            if len(ids):
                assert ds.objects[int(ids[0])].prim_path == path
                assert {ds.classes[c] for c in np.unique(sem[mine])} == {label}
        assert np.all(sem[inst == 0] == 0)


def test_rgb_is_lit_and_matches_linear_exr(plane):
    rgb = plane.read(1, (0, 0), "rgb")
    lin = plane.read(1, (0, 0), "rgb_linear")
    assert rgb.dtype == np.uint8 and rgb.shape == (48, 64, 3)
    assert 20 < rgb.mean() < 235
    # sRGB encoding of the linear image, computed from the standard formula
    x = np.clip(lin, 0, 1)
    s = np.where(x <= 0.0031308, 12.92 * x, 1.055 * x ** (1 / 2.4) - 0.055)
    assert np.abs(rgb.astype(float) - s * 255).max() <= 0.51


def test_camera_poses_equal_the_rig_formula(plane, dome):
    for ds in (plane, dome):
        for view in ds.views:
            np.testing.assert_allclose(ds.cam_to_world(1, view), ds.rig.cam_to_world(view), atol=1e-9)


def test_blender_imports_the_rig_lens(box_dataset, tmp_path):
    """The lens Blender builds from the USD camera equals the rig's (mm), with a horizontal fit."""
    probe = tmp_path / "probe.py"
    probe.write_text(
        "import bpy, json, sys\n"
        "bpy.utils.expose_bundled_modules()\n"
        "bpy.ops.wm.read_factory_settings(use_empty=True)\n"
        f"bpy.ops.wm.usd_import(filepath={str(box_dataset[0])!r})\n"
        "cams = {o.name: [o.data.lens, o.data.sensor_width, o.data.sensor_fit, o.data.clip_start] for o in bpy.data.objects if o.type == 'CAMERA'}\n"
        "print('PROBE' + json.dumps(cams))\n"
    )
    out = subprocess.run([sys.executable, str(probe)], capture_output=True, text=True, check=True).stdout
    cams = json.loads(next(ln for ln in out.splitlines() if ln.startswith("PROBE"))[5:])
    assert len(cams) == len(PLANE_RIG.views) + len(SPHERE_RIG.views)
    for lens, sensor, fit, clip in cams.values():
        assert lens == pytest.approx(39.0, abs=1e-4)
        assert sensor == pytest.approx(36.0, abs=1e-4)
        assert fit in ("HORIZONTAL", "AUTO")
        assert clip <= 0.011


def test_manifest_records_the_render(box_dataset):
    m = json.loads((box_dataset[1] / "manifest.json").read_text())
    assert m["rigs"] == ["dome", "main"] and m["frames"] == [1]
    assert len(m["stage"]["sha256"]) == 64 and m["device"] == "cpu"
    assert {"bpy", "usd-core", "lfusd"} <= set(m["software"])
    assert m["settings"]["rigs"]["main"]["width"] == 64

"""`lfusd view`: recordings read back with rerun's own reader (rerun.chunk.RrdReader, `rerun rrd
print`), checked against the cameras and the geometry: posed cameras, images, the point cloud
projecting back onto its pixels, scene-flow arrows equal to the movers' analytic motion."""

from __future__ import annotations

import collections
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from support.fake import FakeDataset

from lfusd import LfusdError
from lfusd.evaluation.view import entity, grid_step, log_dataset


def read_rrd(path) -> dict:
    """{(entity path, component): {frame: value}} of a recording, through rerun's reader."""
    from rerun.chunk import RrdReader

    out = collections.defaultdict(dict)
    for chunk in RrdReader(path).stream():
        rb = chunk.to_record_batch().to_pydict()
        frames = rb.get("frame", [None] * chunk.num_rows)
        for name, values in rb.items():
            if ":" in name:
                for f, v in zip(frames, values):
                    out[(chunk.entity_path.lstrip("/"), name)][f] = v
    return out


def record(ds, path, rig="main", **kw):
    import rerun as rr

    rec = rr.RecordingStream("test")
    rec.save(str(path))
    counts = log_dataset(rec, ds, rig, ds.frames, [tuple(v) for v in ds.views], **kw)
    rec.flush()
    rec.disconnect()
    return counts


def check_cameras_and_cloud(ds, rec, rig, frames, views, max_points):
    """Every camera posed and imaged each frame; every point of the cloud projects back onto the
    centre-view pixel of the subsampling grid it was taken from, with that pixel's colour."""
    w, h = ds.resolution
    centre = tuple(ds.rig.centre_view)
    K = ds.intrinsics(centre)
    for t in frames:
        for v in views:
            cam = entity(rig, v)
            c2w = ds.cam_to_world(t, v)
            np.testing.assert_allclose(np.array(rec[(cam, "Transform3D:translation")][t]).ravel(), c2w[:3, 3], atol=1e-5)
            np.testing.assert_allclose(np.array(rec[(cam, "Transform3D:mat3x3")][t]).reshape(3, 3).T, c2w[:3, :3], atol=1e-6)  # column-major
            np.testing.assert_allclose(np.array(rec[(cam, "Pinhole:image_from_camera")][t]).reshape(3, 3).T, K, atol=1e-4)
            assert list(np.array(rec[(cam, "Pinhole:resolution")][t]).ravel()) == [w, h]
            assert rec[(entity(rig, v, "rgb"), "EncodedImage:blob")][t] is not None  # JPEG by default
        pts = np.array(rec[(entity(rig, None, "points"), "Points3D:positions")][t], float).reshape(-1, 3)
        s = grid_step(h, w, max_points)
        rows, cols = np.mgrid[0:h:s, 0:w:s]
        depth = ds.read(t, centre, "depth")[::s, ::s]
        assert len(pts) == int(np.isfinite(depth).sum()) > 0
        c2w = ds.cam_to_world(t, centre)
        cam_pts = (pts - c2w[:3, 3]) @ c2w[:3, :3]  # world -> OpenCV camera frame
        uv = cam_pts @ K.T
        uv = uv[:, :2] / uv[:, 2:]
        fin = np.isfinite(depth)
        np.testing.assert_allclose(uv[:, 0], cols[fin], atol=1e-3)
        np.testing.assert_allclose(uv[:, 1], rows[fin], atol=1e-3)
        np.testing.assert_allclose(cam_pts[:, 2], depth[fin], rtol=1e-5)
        colours = np.array(rec[(entity(rig, None, "points"), "Points3D:colors")][t], np.uint32)
        rgb = ds.read(t, centre, "rgb")[::s, ::s][fin].astype(np.uint32)
        np.testing.assert_array_equal(colours, (rgb[:, 0] << 24) | (rgb[:, 1] << 16) | (rgb[:, 2] << 8) | 255)  # RGBA packed


def test_fake_recording_has_posed_cameras_points_and_analytic_arrows(tmp_path):
    from support.fake import V

    ds = FakeDataset(rows=3, cols=3, width=24, height=20, frames=(1, 2, 3))
    ds.resolution = (24, 20)
    counts = record(ds, tmp_path / "fake.rrd", max_points=100, max_arrows=40, arrow_scale=1.0)
    rec = read_rrd(tmp_path / "fake.rrd")
    check_cameras_and_cloud(ds, rec, "main", ds.frames, ds.views, 100)
    assert counts["images"] == 27 and counts["frames"] == 3 and counts["arrow_scale"] == 1.0
    # arrows: the box moves by V (rig frame) per frame, the wall not at all (no arrow there); none on
    # the last frame (no t+1)
    r2w = ds.rig.rig_to_world()[:3, :3]
    for t in (1, 2):
        o = np.array(rec[(entity("main", None, "scene_flow"), "Arrows3D:origins")][t], float).reshape(-1, 3)
        vec = np.array(rec[(entity("main", None, "scene_flow"), "Arrows3D:vectors")][t], float).reshape(-1, 3)
        assert len(o) > 0
        np.testing.assert_allclose(vec, np.broadcast_to(r2w @ V, vec.shape), atol=1e-6)  # only the box: still points get none
    assert 3 not in rec.get((entity("main", None, "scene_flow"), "Arrows3D:origins"), {})
    # the segmentation and flow images of the centre view
    c = ds.rig.centre_view
    assert set(rec[(entity("main", c, "instance"), "SegmentationImage:buffer")]) == {1, 2, 3}
    assert set(rec[(entity("main", c, "flow"), "Image:buffer")]) == {1, 2}


class StreetFake(FakeDataset):
    """The analytic scene stretched to a street's extent: a wall 25 m away that a box crosses by
    3 cm per frame, as lfusd's street scenes move (issue 39.15: arrows invisible at true length)."""

    def _compute(self, t, view, key):
        a = super()._compute(t, view, key)
        return (a * 8.0).astype(a.dtype) if key in ("position", "depth") else a


def test_arrows_get_a_visible_scale_images_are_jpeg_and_the_recording_has_a_layout(tmp_path):
    """Issue 39.15: the default arrow scale makes the 95th percentile moving arrow ARROW_SHARE of the
    cloud's extent, rounded down to 1-2-5, the same at every frame and stated in the recording; still
    points get no arrow; images are JPEG (smaller than raw); the recording carries a blueprint
    (3D world beside the light-field grid, timeline open)."""
    import rerun as rr

    from lfusd.evaluation.view import ARROW_SHARE, layout, nice_scale

    assert [nice_scale(x) for x in (0.7, 1.0, 3.3, 17.0, 499.0)] == [0.5, 1.0, 2.0, 10.0, 200.0]
    ds = StreetFake(rows=2, cols=3, width=24, height=20, frames=(1, 2, 3))
    ds.resolution = (24, 20)
    counts = record(ds, tmp_path / "auto.rrd", max_points=400, max_arrows=400)
    rec = read_rrd(tmp_path / "auto.rrd")
    pts = np.concatenate([np.array(rec[(entity("main", None, "points"), "Points3D:positions")][t], float).reshape(-1, 3) for t in ds.frames])
    true = []
    for t in (1, 2):
        sf = ds.read(t, ds.rig.centre_view, "scene_flow").reshape(-1, 3)
        s = grid_step(20, 24, 400)
        sf = ds.read(t, ds.rig.centre_view, "scene_flow")[::s, ::s].reshape(-1, 3)
        true.append(sf[np.linalg.norm(sf, axis=-1) > 1e-6])
    p95 = np.percentile(np.linalg.norm(np.concatenate(true), axis=-1), 95)
    want = ARROW_SHARE * np.linalg.norm(pts.max(0) - pts.min(0)) / p95
    scale = counts["arrow_scale"]
    assert want / 5 < scale <= want and scale == nice_scale(want) and scale > 1
    for t in (1, 2):
        vec = np.array(rec[(entity("main", None, "scene_flow"), "Arrows3D:vectors")][t], float).reshape(-1, 3)
        np.testing.assert_allclose(vec, true[t - 1] * scale, rtol=1e-5)  # one scale for every frame
    assert f"{scale:g} times" in str(rec[(entity("main", None, "scene_flow_scale"), "TextDocument:text")][None])
    # JPEG images are smaller than raw ones: the images' own bytes (the files' sizes also depend on
    # how rerun batches its chunks, which varies with the machine's load)
    record(ds, tmp_path / "raw.rrd", max_points=400, max_arrows=400, lossless=True)
    raw = read_rrd(tmp_path / "raw.rrd")
    assert (entity("main", (0, 0), "rgb"), "Image:buffer") in raw

    def image_bytes(recording, component):
        return sum(len(np.asarray(v).ravel()) for (e, c), vals in recording.items() if c == component and e.endswith("/rgb")
                   for v in vals.values() if v is not None)

    jpeg, lossless = image_bytes(rec, "EncodedImage:blob"), image_bytes(raw, "Image:buffer")
    assert lossless == len(ds.views) * len(ds.frames) * 24 * 20 * 3  # every image, raw sRGB
    assert 0 < jpeg < lossless
    # the layout: one 2D view per camera in a grid of the rig's columns, beside the 3D world
    bp = tmp_path / "bp.rrd"
    stream = rr.RecordingStream("bp")
    stream.save(str(bp), default_blueprint=layout({"main": (2, 3, ds.views)}))
    stream.log("world", rr.ViewCoordinates.RIGHT_HAND_Z_UP, static=True)
    stream.flush()
    stream.disconnect()
    from rerun.chunk import RrdReader

    reader = RrdReader(bp)
    (store,) = reader.blueprints()
    bp_values = collections.defaultdict(list)
    for chunk in reader.stream(store=store):
        for name, values in chunk.to_record_batch().to_pydict().items():
            if ":" in name:
                bp_values[name.split("@")[-1]] += [v[0] if isinstance(v, list) and len(v) == 1 else v for v in values]
    views = dict(zip(bp_values["ViewBlueprint:space_origin"], bp_values["ViewBlueprint:class_identifier"]))
    assert views.pop("world") == "3D"
    assert views == {entity("main", v): "2D" for v in ds.views}  # one image view per camera
    assert 3 in bp_values["ContainerBlueprint:grid_columns"] and "main light field" in bp_values["ContainerBlueprint:display_name"]
    assert bp_values["TimePanelBlueprint:state"]  # the timeline panel is set (expanded)


def test_view_refuses_bad_requests_in_one_line(tmp_path):
    from lfusd.evaluation.view import view

    with pytest.raises(LfusdError, match="holds no lfusd dataset|does not exist"):
        view(tmp_path / "nothing", save=tmp_path / "x.rrd")
    with pytest.raises(LfusdError, match=r"\.rrd"):
        view(tmp_path, save=tmp_path / "x.txt")
    with pytest.raises(LfusdError, match="positive"):
        view(tmp_path, save=tmp_path / "x.rrd", every=0)


@pytest.fixture(scope="module")
def moving(tmp_path_factory):
    from support.scenes import write_motion_stage

    from lfusd.camera import RigSpec
    from lfusd.cli import main

    root = tmp_path_factory.mktemp("view")
    rig = RigSpec(name="main", rows=3, cols=3, width=40, height=32, baseline=0.1, at=(0.3, -5.0, 1.8), look_at=(0.0, 0.5, 0.6))
    write_motion_stage(root / "movers.usda", rig, 3)
    out = root / "out"
    assert main(["render-video", str(root / "movers.usda"), "-o", str(out), "--samples", "2", "--quiet", "--device", "cpu", "--workers", "2"]) == 0
    return out


@pytest.mark.render
def test_view_saves_a_recording_of_a_rendered_video(moving, tmp_path, capsys):
    from support.scenes import movers_world

    from lfusd import Dataset
    from lfusd.cli import main

    rrd = tmp_path / "movers.rrd"
    assert main(["view", str(moving), "--save", str(rrd), "--max-points", "300", "--max-arrows", "200", "--arrow-scale", "1"]) == 0
    assert "3 frames, 27 images" in capsys.readouterr().out
    ds = Dataset(moving)
    rec = read_rrd(rrd)
    check_cameras_and_cloud(ds, rec, "main", ds.frames, ds.views, 300)
    # every arrow is the analytic motion of the surface point it starts at: inside a mover's box at
    # t it moves with that box, on the ground it stays
    moved = 0
    for t in (1, 2):
        o = np.array(rec[(entity("main", None, "scene_flow"), "Arrows3D:origins")][t], float).reshape(-1, 3)
        vec = np.array(rec[(entity("main", None, "scene_flow"), "Arrows3D:vectors")][t], float).reshape(-1, 3)
        assert len(o) > 0
        expected = np.zeros_like(o)
        for (pose, size), (pose1, _) in zip(movers_world(t).values(), movers_world(t + 1).values()):
            local = (np.c_[o, np.ones(len(o))] @ np.linalg.inv(pose).T)[:, :3]
            on = np.all(np.abs(local) <= size / 2 + 1e-3, axis=1)
            expected[on] = (np.c_[o[on], np.ones(on.sum())] @ (pose1 @ np.linalg.inv(pose)).T)[:, :3] - o[on]
            moved += int(on.sum())
        np.testing.assert_allclose(vec, expected, atol=2e-3)
    assert moved > 0
    # rerun's command-line reader opens it and lists the archetypes
    rerun = Path(sys.executable).with_name("rerun")
    listing = subprocess.run([str(rerun), "rrd", "print", "-v", str(rrd)], capture_output=True, text=True, timeout=120)
    assert listing.returncode == 0, listing.stderr
    for arche in ("Pinhole", "Transform3D", "Image", "Points3D", "Arrows3D", "DepthImage", "SegmentationImage"):
        assert f"{arche}:" in listing.stdout
    # --views / --frames / --every keep it light; a second save never overwrites
    light = tmp_path / "light.rrd"
    assert main(["view", str(moving), "--save", str(light), "--views", "1,1", "0,0", "--frames", "1-3", "--every", "2"]) == 0
    rec = read_rrd(light)
    assert set(rec[(entity("main", (0, 0), "rgb"), "EncodedImage:blob")]) == {1, 3}
    assert (entity("main", (0, 1), "rgb"), "EncodedImage:blob") not in rec
    assert main(["view", str(moving), "--save", str(light)]) == 2


@pytest.mark.render
def test_view_without_a_display_says_to_save_instead(tmp_path, monkeypatch, capsys, box_dataset):
    """Headless (no DISPLAY / WAYLAND_DISPLAY): one line pointing at --save, nothing spawned."""
    from lfusd.cli import main

    if not sys.platform.startswith("linux"):
        pytest.skip("the display check is Linux's")
    monkeypatch.delenv("DISPLAY", raising=False)
    monkeypatch.delenv("WAYLAND_DISPLAY", raising=False)
    _, out = box_dataset
    assert main(["view", str(out), "--rig", "main"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("lfusd: error: no display") and "--save FILE.rrd" in err[0]


@pytest.mark.render
def test_view_of_a_still_dataset_with_two_rigs(tmp_path, box_dataset, capsys):
    """Every rig under its own path (a planar 3x3 and a spherical 2x3 rig), no arrows without motion."""
    from lfusd import Dataset
    from lfusd.cli import main

    _, out = box_dataset
    assert main(["view", str(out), "--save", str(tmp_path / "boxes.rrd"), "--max-points", "500"]) == 0
    printed = capsys.readouterr().out
    rec = read_rrd(tmp_path / "boxes.rrd")
    for rig in ("main", "dome"):
        ds = Dataset(out, rig=rig)
        assert f"{rig}: {len(ds.frames)} frames, {len(ds.frames) * len(ds.views)} images" in printed
        check_cameras_and_cloud(ds, rec, rig, ds.frames, ds.views, 500)
        assert (entity(rig, None, "scene_flow"), "Arrows3D:origins") not in rec


def test_the_recording_shows_the_camera_effects_the_dataset_has(tmp_path):
    class Effects(FakeDataset):
        def read(self, frame, view, key):
            depth = super().read(frame, view, "depth")
            if key == "rgb_noisy":
                return 255 - super().read(frame, view, "rgb")
            if key in ("transmissive", "emissive"):
                return np.isfinite(depth) & (np.arange(depth.shape[1]) < depth.shape[1] // 2)
            if key == "mirror":
                return np.zeros(depth.shape, bool)
            if key == "coc":
                return np.abs(1 / 2.0 - 1 / depth).astype(np.float32)
            return super().read(frame, view, key)  # blur: none (KeyError), like a render without --shutter

    ds = Effects(rows=1, cols=1, width=24, height=20, frames=(1, 2))
    ds.resolution = (24, 20)
    record(ds, tmp_path / "fx.rrd")
    rec = read_rrd(tmp_path / "fx.rrd")
    centre = tuple(ds.rig.centre_view)
    for key in ("rgb_noisy", "materials", "coc"):
        assert any(e == entity("main", centre, key) for e, _ in rec), key
    assert not any(e == entity("main", centre, "blur") for e, _ in rec)
    labels = np.array(rec[(entity("main", centre, "materials"), "SegmentationImage:buffer")][1], np.uint8)
    assert set(np.unique(labels)) <= {0, 5}  # transmissive (1) and emissive (4) together

"""Format version 2 (lfusd.data.store) against closed-form ground truth, and Dataset reading versions 1 and 2.

The truth is a ray-cast scene (tests/support/analytic.py): depth, instance, normals of the hit
faces, and the motion of a box translated between frames, projected with K and the pose."""

from __future__ import annotations

import json
from dataclasses import replace

import numpy as np
import OpenEXR
import pytest
from support.analytic import cast, cast_uv, pixel_rays, project
from support.scenes import GROUND_HALF, PLANE_RIG, boxes_world

from lfusd import Dataset, LfusdError, keys, layout
from lfusd.data import integrity, passes, store
from lfusd.data.formats import write_png

VIEW = (1, 1)
MOVE = np.array([0.137, -0.061, 0.023])  # metres: BoxB between frame t and t+1 (not a multiple of any step)
MOVED = "/World/BoxB"


def _normals(points, names, boxes):
    """Unit normal of the face each ray hit: +z on the ground, the box face's outward normal otherwise."""
    n = np.full(points.shape, np.nan)
    n[names == "ground"] = (0, 0, 1)
    for name, (m, size) in boxes.items():
        sel = names == name
        local = (points[sel] - m[:3, 3]) @ m[:3, :3]  # box frame
        axis = np.argmax(np.abs(local), axis=-1)
        nl = np.zeros_like(local)
        nl[np.arange(len(local)), axis] = np.sign(local[np.arange(len(local)), axis])
        n[sel] = nl @ m[:3, :3].T
    return n


def analytic_view():
    """Every stored key of one view of the box scene, from closed-form ray casts (float64 truth)."""
    K, c2w = PLANE_RIG.intrinsics(), PLANE_RIG.cam_to_world(VIEW)
    w, h = PLANE_RIG.width, PLANE_RIG.height
    boxes = boxes_world()
    depth, names = cast(K, c2w, w, h, boxes, GROUND_HALF)
    fg = np.isfinite(depth)
    origin, dirs = pixel_rays(K, c2w, w, h)
    P = origin + np.where(fg, depth, 0)[..., None] * dirs
    moving = names == MOVED
    P1 = P + np.where(moving[..., None], MOVE, 0)
    P0 = P - np.where(moving[..., None], MOVE, 0)  # the same motion before t
    v, u = np.mgrid[0:h, 0:w].astype(np.float64)
    with np.errstate(divide="ignore", invalid="ignore"):  # background rays project nowhere (masked)
        fwd = np.where(fg[..., None], project(K, c2w, P1) - np.stack([u, v], -1), 0)
        bwd = np.where(fg[..., None], project(K, c2w, P0) - np.stack([u, v], -1), 0)
    z1 = ((P1 - c2w[:3, 3]) @ c2w[:3, :3])[..., 2]
    fb = K[0, 0] * PLANE_RIG.baseline
    moved = dict(boxes)
    moved[MOVED] = (boxes[MOVED][0].copy(), boxes[MOVED][1])
    moved[MOVED][0][:3, 3] += MOVE  # the scene at t+1
    seen = cast_uv(K, c2w, (fwd + np.stack([u, v], -1)).reshape(-1, 2), moved, GROUND_HALF).reshape(h, w)
    ids = {"": 0, "ground": 1, "/World/BoxA": 2, MOVED: 3}
    with np.errstate(divide="ignore", invalid="ignore"):
        truth = {
            "depth": np.where(fg, depth, np.inf).astype(np.float32),
            "normal": _normals(P, names, boxes).astype(np.float32),
            "instance": np.vectorize(ids.get)(names).astype(np.int32),
            "flow_fwd": fwd.astype(np.float32), "flow_bwd": bwd.astype(np.float32),
            "scene_flow": np.where(fg[..., None], P1 - P, 0).astype(np.float32),
            "disparity_change": np.where(fg, fb / z1 - fb / depth, 0).astype(np.float32),
            "valid_fwd": fg, "valid_bwd": fg,
            "occlusion_fwd": fg & (seen < z1 * (1 - 1e-6)), "occlusion_bwd": np.zeros_like(fg),
        }
    return truth, P, K, c2w


def test_every_stored_key_round_trips_within_its_storage_error(tmp_path):
    truth, *_ = analytic_view()
    assert truth["occlusion_fwd"].any() and (truth["flow_fwd"] != 0).any() and np.isnan(truth["normal"]).any()
    static = {k: truth[k] for k in ("depth", "normal", "instance")}
    motion = {k: v for k, v in truth.items() if k not in static}
    for name, arrays in (("gt.exr", static), ("motion.exr", motion)):
        path = store.write(tmp_path / name, arrays)
        assert store.check(path, arrays) == len(arrays) * PLANE_RIG.width * PLANE_RIG.height
        # what derivation writes: checked bit for bit (NaN normals included), counted as check counts
        assert store.write_checked(tmp_path / f"checked_{name}", arrays)[1] == len(arrays) * PLANE_RIG.width * PLANE_RIG.height
        assert (tmp_path / f"checked_{name}").read_bytes() == path.read_bytes()
        back = store.read(path)
        assert set(back) == set(arrays)
        for key, want in arrays.items():
            got, st = back[key], keys.KEYS[key].storage
            assert got.dtype == np.dtype(keys.KEYS[key].dtype) and got.shape == want.shape, key
            if st.encoding == "fixed":
                err = np.abs(got.astype(np.float64) - want)
                assert err.max() <= 2.0 ** -(st.bits + 1) + 1e-12, key
                assert err.max() > 0, key  # the rounding did happen: the bound is the one tested
                steps = got.astype(np.float64) * 2.0**st.bits
                assert np.array_equal(steps, np.round(steps)), key  # multiples of the step, which ZIP compresses
            elif st.encoding == "half":
                fin = np.isfinite(want)
                assert np.array_equal(np.isnan(got), np.isnan(want))
                err = np.abs(got[fin].astype(np.float64) - want[fin])
                assert err.max() <= 2.0**-12 and err.max() > 0, key
            else:  # lossless: depth, instance, masks
                np.testing.assert_array_equal(got, want, err_msg=key)


@pytest.mark.parametrize("far", [False, True], ids=["flow-below-256px", "flow-of-300.3px"])
def test_motion_files_are_pxr24_only_where_it_keeps_every_bit(tmp_path, far):
    """PXR24 keeps a float's top 24 bits: fixed-point flow below 2^16 steps fits them, a flow of
    300.3 px (17 significant bits) and a full-precision depth do not, and those files are ZIP.
    Either way every channel reads back bit for bit."""
    truth, *_ = analytic_view()
    motion = {k: truth[k] for k in ("flow_fwd", "scene_flow", "disparity_change", "valid_fwd", "occlusion_fwd")}
    if far:
        motion["flow_fwd"] = motion["flow_fwd"].copy()
        motion["flow_fwd"][0, 0, 0] = 300.3
    path, _ = store.write_checked(tmp_path / "motion.exr", motion)
    want = OpenEXR.ZIP_COMPRESSION if far else OpenEXR.PXR24_COMPRESSION
    assert OpenEXR.File(str(path)).header()["compression"] == want
    back = store.read(path)
    for key, a in store.encode(motion).items():
        got = store.encode({k: back[k] for k in motion})[key]
        assert np.array_equal(got.view(np.uint8), a.view(np.uint8)), key
    if far:
        assert back["flow_fwd"][0, 0, 0] == np.float32(round(300.3 * 256) / 256)
    static = {k: truth[k] for k in ("depth", "normal", "instance")}
    gt, _ = store.write_checked(tmp_path / "gt.exr", static)
    assert OpenEXR.File(str(gt)).header()["compression"] == OpenEXR.ZIP_COMPRESSION  # depth uses all 32 bits


def test_a_file_that_reads_back_different_fails_the_check(tmp_path):
    truth, *_ = analytic_view()
    arrays = {"flow_fwd": truth["flow_fwd"], "valid_fwd": truth["valid_fwd"]}
    path = store.write(tmp_path / "motion.exr", arrays)
    store.write(path, {"flow_fwd": truth["flow_fwd"] + 0.01, "valid_fwd": truth["valid_fwd"]})
    with pytest.raises(LfusdError, match="flow_fwd read back off by") as e:
        store.check(path, arrays)
    assert "\n" not in str(e.value)


def test_a_file_written_other_than_encoded_fails_the_bitwise_check(tmp_path, monkeypatch):
    truth, *_ = analytic_view()
    arrays = {"flow_fwd": truth["flow_fwd"], "valid_fwd": truth["valid_fwd"]}
    real = store._write

    def one_step_off(path, arrays, channels):  # a write that lands one stored step off on one channel
        return real(path, arrays, {**channels, "flow_fwd.X": channels["flow_fwd.X"] + np.float32(2.0**-8)})

    monkeypatch.setattr(store, "_write", one_step_off)
    with pytest.raises(LfusdError, match="channel flow_fwd.X did not read back as written") as e:
        store.write_checked(tmp_path / "motion.exr", arrays)
    assert "\n" not in str(e.value)


def test_position_computed_from_depth_is_the_analytic_hit_point():
    truth, P, K, c2w = analytic_view()
    pos = passes.position(truth["depth"], K, c2w)
    fg = np.isfinite(truth["depth"])
    assert pos.dtype == np.float32 and np.isnan(pos[~fg]).all() and fg.sum() > 1000
    dist = np.linalg.norm(P[fg] - c2w[:3, 3], axis=-1)
    err = np.linalg.norm(pos[fg] - P[fg], axis=-1)
    assert (err <= 2e-7 * dist + 2e-6).all(), err.max()  # float32 depth and result


def test_stored_keys_and_key_validation():
    assert set(keys.stored(["position", "semantic", "rgb"])) == {"depth", "instance", "rgb"}
    assert set(keys.stored(["rgb", "rgb_linear", "disparity"])) == {"rgb_linear", "depth"}
    everything = keys.check_wanted(None, motion=True, keep_raw=False)
    assert "vector" not in everything and "flow_fwd" in everything
    for wanted, motion, keep, match in ((["flow_fwd"], False, False, "motion keys need 'lfusd render-video'"),
                                        (["vector"], True, False, "add --keep-raw"),
                                        (["dpeth"], True, False, "unknown ground-truth key 'dpeth'")):
        with pytest.raises(LfusdError, match=match) as e:
            keys.check_wanted(wanted, motion, keep)
        assert "\n" not in str(e.value)


# -- Dataset on hand-made folders of format versions 1 and 2 -----------------------------------------


ONE = (0, 0)  # the view of the one-view rig the hand-made datasets hold: PLANE_RIG's centre camera


def _folder(root, version, settings_extra):
    spec = replace(PLANE_RIG, rows=1, cols=1).to_dict()
    manifest = {"format": layout.FORMAT, "version": version, "id": "x", "rigs": [PLANE_RIG.name], "frames": [1],
                "settings": {"rigs": {PLANE_RIG.name: spec}, "motion": True, **settings_extra}}
    root.mkdir(parents=True)
    (root / layout.MANIFEST).write_text(json.dumps(manifest))
    objects = [{"id": i, "prim_path": p, "label": l, "class_id": c} for i, p, l, c in
               ((1, "/World/ground", "ground", 1), (2, "/World/BoxA", "crate", 2), (3, MOVED, "drone", 3))]
    (root / layout.OBJECTS).write_text(json.dumps({"classes": ["unlabelled", "ground", "crate", "drone"], "objects": objects}))
    fd = layout.frame_dir(root, PLANE_RIG.name, 1)
    d = fd / layout.view_key(ONE)
    d.mkdir(parents=True)
    poses = {layout.view_key(ONE): PLANE_RIG.cam_to_world(VIEW).tolist()}
    (fd / layout.FRAME_META).write_text(json.dumps({"cam_to_world": poses, "object_poses": {o["prim_path"]: np.eye(4).tolist() for o in objects}}))
    return d


def test_a_format_version_1_dataset_still_reads(tmp_path):
    """Version 1 files, written the way lfusd wrote them before format 2 (Blender's multilayer
    channel names, motion.npz, a version 1 record), read back key by key."""
    truth, P, K, c2w = analytic_view()
    root = tmp_path / "v1"
    d = _folder(root, 1, {})
    h, w = truth["depth"].shape
    fg = np.isfinite(truth["depth"])
    rng = np.random.default_rng(0)
    vector = rng.normal(size=(h, w, 4)).astype(np.float32)
    nxt = np.where(fg[..., None], P + MOVE, np.nan).astype(np.float32)
    ch = {"ViewLayer.Depth.Z": np.where(fg, truth["depth"], 1e10).astype(np.float32),
          "ViewLayer.Object Index.X": truth["instance"].astype(np.float32)}
    for name, arr in (("Normal", np.nan_to_num(truth["normal"])), ("Position", np.nan_to_num(P.astype(np.float32))), ("Vector", vector)):
        ch.update({f"ViewLayer.{name}.{c}": np.ascontiguousarray(arr[..., i]) for i, c in enumerate("XYZW"[: arr.shape[-1]])})
    ch.update({f"ViewLayer.next_position.{c}": np.ascontiguousarray(np.nan_to_num(nxt)[..., i]) for i, c in enumerate("RGB")})
    ch["ViewLayer.next_position.A"] = np.ones((h, w), np.float32)
    OpenEXR.File({"compression": OpenEXR.ZIP_COMPRESSION, "type": OpenEXR.scanlineimage}, ch).write(str(d / layout.PASSES_EXR))
    rgb = rng.uniform(0, 1, (h, w, 3)).astype(np.float16)
    OpenEXR.File({"compression": OpenEXR.ZIP_COMPRESSION, "type": OpenEXR.scanlineimage}, {"RGB": rgb}).write(str(d / layout.RGB_EXR))
    write_png(d / layout.RGB_PNG, passes.linear_to_srgb8(rgb.astype(np.float32)))
    # format version 1 predates mixed and the camera effects (blur)
    motion = {k: truth[k] for k in keys.names(keys.MOTION) if k != "mixed" and keys.KEYS[k].effect is None}
    np.savez(d / layout.MOTION_FILE_V1, **motion)
    files = {n: integrity.file_entry(d / n) for n in (layout.RGB_PNG, layout.RGB_EXR, layout.PASSES_EXR, layout.MOTION_FILE_V1)}
    (d / layout.VIEW_RECORD).write_text(json.dumps({"version": 1, "files": files}))

    ds = Dataset(root)
    assert ds.version == 1 and ds.frames == [1] and integrity.render_problems(d) == []
    np.testing.assert_array_equal(ds.read(1, ONE, "depth"), truth["depth"])
    np.testing.assert_array_equal(ds.read(1, ONE, "instance"), truth["instance"])
    np.testing.assert_array_equal(ds.read(1, ONE, "semantic"), truth["instance"])  # class id = instance id here
    np.testing.assert_array_equal(ds.read(1, ONE, "vector"), vector)
    np.testing.assert_array_equal(ds.read(1, ONE, "position")[fg], P[fg].astype(np.float32))  # v1: Blender's position pass
    np.testing.assert_array_equal(ds.read(1, ONE, "next_position")[fg], nxt[fg])
    np.testing.assert_array_equal(ds.read(1, ONE, "rgb_linear"), rgb.astype(np.float32))
    np.testing.assert_array_equal(ds.read(1, ONE, "rgb"), passes.linear_to_srgb8(rgb.astype(np.float32)))
    for k, v in motion.items():
        np.testing.assert_array_equal(ds.read(1, ONE, k), v, err_msg=k)


def test_a_format_version_2_dataset_reads_what_it_stored_and_names_what_it_did_not(tmp_path):
    truth, P, K, c2w = analytic_view()
    root = tmp_path / "v2"
    wanted = ["rgb", "position", "semantic", "flow_fwd", "valid_fwd"]
    d = _folder(root, 2, {"keys": wanted, "keep_raw": False})
    store.write(d / layout.GT_FILE, {"depth": truth["depth"], "instance": truth["instance"]})
    store.write(d / layout.MOTION_FILE, {"flow_fwd": truth["flow_fwd"], "valid_fwd": truth["valid_fwd"]})
    rgb8 = np.random.default_rng(1).integers(0, 256, truth["normal"].shape, dtype=np.uint8)
    write_png(d / layout.RGB_PNG, rgb8)
    integrity.record_files(d, {layout.GT_FILE: {"checked": 1}, layout.MOTION_FILE: {}, layout.RGB_PNG: {}})
    ds = Dataset(root)
    assert ds.version == 2 and ds.frames == [1]
    fg = np.isfinite(truth["depth"])
    pos = ds.read(1, ONE, "position")
    assert np.abs(pos[fg] - P[fg]).max() < 1e-4 and np.isnan(pos[~fg]).all()
    np.testing.assert_array_equal(ds.read(1, ONE, "semantic"), truth["instance"])
    np.testing.assert_array_equal(ds.read(1, ONE, "rgb"), rgb8)
    np.testing.assert_array_equal(ds.read(1, ONE, "valid_fwd"), truth["valid_fwd"])
    assert np.abs(ds.read(1, ONE, "flow_fwd") - truth["flow_fwd"]).max() <= 2.0**-9
    for key, match in (("normal", "key 'normal' was not written .*--keys rgb,position"), ("flow_bwd", "not written"),
                       ("vector", "raw passes .* removed .*--keep-raw")):
        with pytest.raises(LfusdError, match=match) as e:
            ds.read(1, ONE, key)
        assert "\n" not in str(e.value)


def test_removed_raw_passes_keep_their_digest_for_the_neighbours_inputs(tmp_path):
    d = tmp_path / "v"
    d.mkdir()
    (d / layout.RGB_EXR).write_bytes(b"rgb")
    (d / layout.PASSES_EXR).write_bytes(b"raw passes")
    integrity.record_render(d)
    sha = integrity.file_entry(d / layout.PASSES_EXR)["sha256"]
    assert integrity.motion_inputs({"cur": d / layout.PASSES_EXR})["cur"] == sha
    store.write(d / layout.GT_FILE, {"instance": np.ones((2, 2), np.int32)})
    integrity.record_files(d, {layout.GT_FILE: {}}, remove=(layout.PASSES_EXR,))
    (d / layout.PASSES_EXR).unlink()
    assert integrity.render_problems(d) == []  # a removed file is not missing
    assert integrity.motion_inputs({"cur": d / layout.PASSES_EXR})["cur"] == sha
    integrity.record_files(d, annotate={layout.PASSES_EXR: {"pixels": "p" * 64}})
    assert integrity.motion_inputs({"cur": d / layout.PASSES_EXR})["cur"] == "p" * 64  # pixels, not the file's header
    (d / layout.GT_FILE).write_bytes(b"cut")
    assert integrity.render_problems(d) == [f"{layout.GT_FILE} has 3 bytes, the record {integrity.read_record(d)['files'][layout.GT_FILE]['size']}"]


@pytest.mark.parametrize("name", ["flow_fwd", "scene_flow"])
def test_fixed_point_rounding_in_float32_is_the_float64_definition(name):
    """quantize rounds float32 input in float32: bit for bit the definition (round(a * 2^bits) / 2^bits
    in float64), on ties, signed zeros, values beyond 2^(23-bits) (nothing to round), near float32's
    largest (where a * 2^bits overflows float32), inf and NaN."""
    bits = keys.KEYS[name].storage.bits
    rng = np.random.default_rng(7)
    step = 2.0**-bits
    edge = [0.0, -0.0, step / 2, -step / 2, 1.5 * step, -2.5 * step, 2.0 ** (23 - bits), 2.0 ** (23 - bits) - step / 2,
            2.0 ** (24 - bits) + 1, 3.0e38, -3.4e38, np.inf, -np.inf, np.nan, 1e-30, -1e-40]
    a = np.concatenate([np.array(edge, np.float32),
                        (rng.standard_normal(200_000) * 10.0 ** rng.integers(-9, 12, 200_000)).astype(np.float32),
                        (rng.integers(-10**6, 10**6, 50_000) * step + step / 2).astype(np.float32)])  # ties
    want = (np.round(a.astype(np.float64) * 2.0**bits) / 2.0**bits).astype(np.float32)
    got = store.quantize(name, a)
    assert got.dtype == np.float32
    same = (got.view(np.uint32) == want.view(np.uint32)) | (np.isnan(got) & np.isnan(want))
    assert same.all(), a[~same][:5]
    assert (np.signbit(got) == np.signbit(want)).all()

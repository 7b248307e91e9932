"""The ``things`` training templates (lfusd.author.scenes.things): a seed gives the same bytes; the rigs
give HCI-style signed disparity of both signs within +-4 px (+-16 px for ``things_large``) per view step
once each view is shifted by the stage's ``shift_px`` per grid step, proved from the stage's geometry
and rigs alone (depths of every vertex at every frame, the backdrop's face covering every view); a tiny
render passes ``lfusd verify`` and its disparity lands inside the designed range with both signs."""

from __future__ import annotations

import hashlib

import numpy as np
import pytest
from pxr import Usd, UsdGeom

from lfusd import LfusdError
from lfusd.author.labels import object_table
from lfusd.author.rigs import rigs
from lfusd.author.rules import Checker
from lfusd.author.scenes import generate
from lfusd.author.vocabulary import DISPARITY


def _digest(folder):
    return {p.name: hashlib.sha256(p.read_bytes()).hexdigest() for p in sorted(folder.rglob("*")) if p.is_file()}


def test_a_seed_gives_a_byte_identical_dynamic_stage_and_textures(tmp_path):
    args = dict(frames=4, rigs=2, grid=(9, 9), resolution=(256, 256), dynamic=True)
    for name in ("a", "b"):
        generate("things", tmp_path / name / "s.usda", 11, **args)
    generate("things", tmp_path / "c" / "s.usda", 12, **args)
    assert _digest(tmp_path / "a") == _digest(tmp_path / "b")
    assert (tmp_path / "a" / "s.usda").read_bytes() != (tmp_path / "c" / "s.usda").read_bytes()


def _world_points(stage, prim, frame):
    """World vertices (N, 3) of every mesh under ``prim`` at ``frame`` (column-vector maths)."""
    out = []
    for d in Usd.PrimRange(prim):
        if d.IsA(UsdGeom.Mesh):
            m = np.array(UsdGeom.Xformable(d).ComputeLocalToWorldTransform(frame), float).T
            p = np.array(UsdGeom.Mesh(d).GetPointsAttr().Get(frame), float)
            out.append(p @ m[:3, :3].T + m[:3, 3])
    return np.concatenate(out)


def disparity_bounds(stage):
    """From the stage alone, per rig: (the lowest and highest disparity any visible surface can have
    after the shift, proof that some centre-view pixel is positive, proof that some is negative), with
    the shift k read from ``lfusd:disparity`` and everything else from geometry and rig parameters.

    A parallel rig looking along its forward axis sees a point at planar depth z = (p - at) . forward at
    d = f_px * b / z per view step. The backdrop's front face (a plane facing the rig) covers every view,
    so no visible surface is deeper than it; every other vertex at every frame bounds the near side
    (the meshes are closed and the nearest point of a polygon seen in front of the plane is at least
    as deep as its nearest vertex). Positive: an object that lies wholly nearer than z0 = f_px*b/k at
    every frame and projects inside the centre view: the pixels it covers see it or something nearer.
    Negative: the objects' projected boxes (every vertex, every frame) leave some centre-view pixel free:
    that pixel sees the backdrop at d = f_px*b/far - k."""
    k = stage.GetDefaultPrim().GetCustomDataByKey(DISPARITY)["shift_px"]
    first, last = int(stage.GetStartTimeCode()), int(stage.GetEndTimeCode())
    objects = [o for o in object_table(stage)[0]]
    back = [o for o in objects if o.prim_path == "/World/Backdrop"]
    assert len(back) == 1
    pts = {o.prim_path: np.stack([_world_points(stage, stage.GetPrimAtPath(o.prim_path), f) for f in range(first, last + 1)])
           for o in objects}
    out = {}
    for name, rig in rigs(stage).items():
        s = rig.spec
        assert s.axes == "parallel" and s.layout == "plane" and s.spacing == "uniform"
        pose = s.rig_to_world()
        fwd, at = pose[:3, 2], pose[:3, 3]
        fb = s.focal_px * s.baseline
        # the backdrop's front face: a plane perpendicular to the view axis, covering every view's frustum there
        bp = pts["/World/Backdrop"][0] - at
        depth_b = bp @ fwd
        far = depth_b.min()
        face = bp[np.abs(depth_b - far) < 1e-6]
        lo, hi = (face @ pose[:3, :2]).min(0), (face @ pose[:3, :2]).max(0)  # its extent along the rig's x and y
        for view in s.views:
            c = s.view_in_rig(view)[:3, 3]  # the camera in the rig frame (parallel: same axes)
            half = np.array([(s.width / 2) / s.focal_px, (s.height / 2) / s.focal_px]) * (far - c[2])
            assert np.all(lo <= c[:2] - half) and np.all(c[:2] + half <= hi), (name, view)
        near = min(float(((p - at) @ fwd).min()) for path, p in pts.items() if path != "/World/Backdrop")
        assert near > 0
        d_hi, d_lo = fb / near - k, fb / far - k
        # positive: an object wholly nearer than the zero plane, inside the centre view at every frame
        K = s.intrinsics()
        positive = negative = False
        free = np.ones((s.height, s.width), bool)
        for path, p in pts.items():
            if path == "/World/Backdrop":
                continue
            cam = (p - at) @ pose[:3, :3]  # (F, N, 3) in the centre camera's frame (the rig's own)
            u = K[0, 0] * cam[..., 0] / cam[..., 2] + K[0, 2]
            v = K[1, 1] * cam[..., 1] / cam[..., 2] + K[1, 2]
            inside = (u > -0.5) & (u < s.width - 0.5) & (v > -0.5) & (v < s.height - 0.5)
            if np.all(cam[..., 2] < fb / k) and np.all(inside) and np.all(cam[..., 2] > 0):
                positive = True
            for f in range(cam.shape[0]):
                c0, c1 = int(np.floor(u[f].min() + 0.5)), int(np.ceil(u[f].max() + 0.5))
                r0, r1 = int(np.floor(v[f].min() + 0.5)), int(np.ceil(v[f].max() + 0.5))
                free[max(r0, 0):max(r1, 0), max(c0, 0):max(c1, 0)] = False
        negative = bool(free.any()) and d_lo < 0
        out[name] = (d_lo, d_hi, positive, negative)
    return out


@pytest.mark.parametrize("template, limit", [("things", 4.0), ("things_large", 16.0)])
def test_rigs_give_disparity_of_both_signs_within_the_range(tmp_path, template, limit):
    for seed in (0, 1, 2):
        stage = generate(template, tmp_path / f"{template}_{seed}.usda", seed, frames=6, rigs=3, grid=(9, 9),
                         resolution=(512, 512), dynamic=True)
        design = stage.GetDefaultPrim().GetCustomDataByKey(DISPARITY)
        assert design["range_px"] == limit and design["width_px"] == 512
        for name, (lo, hi, positive, negative) in disparity_bounds(stage).items():
            assert -limit <= lo < 0 < hi <= limit, (template, seed, name, lo, hi)
            assert positive and negative, (template, seed, name)
            # a range worth training on: at least 3/4 of the allowed span is used
            assert hi - lo > 0.6 * 2 * limit, (template, seed, name, lo, hi)
        # random baselines: the design varies with the seed
        assert [v.line() for v in Checker(stage).check()] == []


def test_baselines_are_random_and_every_source_of_things_appears(tmp_path):
    baselines, labels, finishes = set(), set(), set()
    for seed in range(3):
        stage = generate("things", tmp_path / f"t{seed}.usda", seed, frames=1, rigs=1, grid=(9, 9), resolution=(512, 512))
        baselines.add(round(rigs(stage)["rig_00"].spec.baseline, 6))
        labels |= {o.label for o in object_table(stage)[0]}
        for p in stage.Traverse():
            if p.GetName() == "Surface" and p.GetAttribute("inputs:metallic"):
                finishes.add((p.GetAttribute("inputs:metallic").Get(), p.GetAttribute("inputs:roughness").Get() < 0.35))
                assert not p.GetAttribute("inputs:opacity")  # nothing transparent
    assert len(baselines) == 3
    assert {"shape", "wall"} <= labels and len(labels - {"shape", "wall"}) >= 3, labels  # props of several classes
    assert {(0.0, False), (0.0, True), (1.0, True)} <= finishes  # matte, glossy and metallic


def test_a_grid_too_wide_for_the_range_is_refused(tmp_path):
    with pytest.raises(LfusdError, match="larger --resolution or a smaller --grid"):
        generate("things_large", tmp_path / "s.usda", 0, frames=1, rigs=1, grid=(9, 9), resolution=(32, 32))
    assert not (tmp_path / "s.usda").exists()


@pytest.mark.render
def test_a_tiny_render_verifies_and_its_disparity_has_both_signs_in_range(tmp_path):
    from support.wild import render_and_verify

    stage_path = tmp_path / "things.usda"
    stage = generate("things", stage_path, 0, frames=2, rigs=1, grid=(3, 3), resolution=(32, 32), dynamic=True)
    k = stage.GetDefaultPrim().GetCustomDataByKey(DISPARITY)["shift_px"]
    ds, _ = render_and_verify(stage_path, tmp_path / "out", "--frames", "1-2", "--rig", "all")
    for f in (1, 2):
        d = np.asarray(ds.read(f, (1, 1), "disparity"), float)[np.isfinite(ds.read(f, (1, 1), "depth"))] - k
        assert d.size > 0.9 * 32 * 32  # the backdrop fills what the things leave
        assert -4.0 <= d.min() < 0 < d.max() <= 4.0, (d.min(), d.max())
        assert (d < 0).sum() >= 10 and (d > 0).sum() >= 10  # the anchor takes 2-10 % of the view


def test_a_recipe_scene_record_keeps_the_disparity_design(tmp_path):
    from lfusd.recipe import disparity_design

    stage = generate("things", tmp_path / "t.usda", 4, frames=1, rigs=1, grid=(9, 9), resolution=(256, 256))
    design = disparity_design(tmp_path / "t.usda")
    assert design == dict(stage.GetDefaultPrim().GetCustomDataByKey(DISPARITY)) and isinstance(design["shift_px"], int)
    fb = rigs(stage)["rig_00"].spec.focal_px * rigs(stage)["rig_00"].spec.baseline
    assert design["zero_m"] == pytest.approx(fb / design["shift_px"], rel=1e-5)
    generate("room", tmp_path / "r.usda", 4, frames=1, rigs=1, grid=(1, 1), resolution=(32, 32))
    assert disparity_design(tmp_path / "r.usda") is None


def test_catalogue_assets_fly_too_and_the_design_holds(tmp_path, capsys):
    """A catalogue's cars stand in for the kit's (at their own size, where one fits): they fly like the
    other things, lfusd's rules hold at every frame and so do the disparity bounds."""
    from support.catalogue_assets import write_car
    from support.cli import run_cli

    from lfusd.author.vocabulary import ASSET

    lib = tmp_path / "library"
    write_car(lib)
    assert run_cli(capsys, "assets", "add", lib)[0] == 0
    found = []
    for seed in range(4):
        stage = generate("things", tmp_path / f"t{seed}.usda", seed, frames=4, rigs=1, grid=(9, 9), resolution=(512, 512),
                         dynamic=True, catalogues=[lib / "catalogue.json"])
        found += [o.prim_path for o in object_table(stage)[0] if stage.GetPrimAtPath(o.prim_path).HasAttribute(ASSET)]
        assert [v.line() for v in Checker(stage).check()] == []
        for lo, hi, positive, negative in disparity_bounds(stage).values():
            assert -4.0 <= lo < 0 < hi <= 4.0 and positive and negative
    assert found

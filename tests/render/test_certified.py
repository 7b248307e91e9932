"""Certified ground truth on Blender renders: every pixel right or flagged (docs/CONVENTIONS.md).

- a static thin pole (long sliver triangles) seen by a static camera has exactly zero flow;
- a mesh whose vertex order changes between frames (same count, as simulation caches write) is
  flagged invalid with one warning naming it, never labelled with motion copied by index;
and verify passes on both, comparing every foreground pixel.
"""

from __future__ import annotations

import numpy as np
import pytest
from pxr import Gf, UsdGeom, Vt

from lfusd import Dataset
from lfusd.author.labels import set_class_label
from lfusd.author.rigs import add_rig
from lfusd.author.stage import new_stage
from lfusd.camera import RigSpec
from lfusd.truth.verify import verify_dataset

pytestmark = pytest.mark.render

RIG = RigSpec(name="main", rows=1, cols=2, baseline=0.1, width=64, height=48, at=(0, -4.0, 1.0), look_at=(0, 0, 1.0))


def _mesh(stage, path, points, faces, label):
    m = UsdGeom.Mesh.Define(stage, path)
    m.CreatePointsAttr(Vt.Vec3fArray([Gf.Vec3f(*map(float, p)) for p in points]))
    m.CreateFaceVertexCountsAttr([len(f) for f in faces])
    m.CreateFaceVertexIndicesAttr([int(i) for f in faces for i in f])
    m.CreateSubdivisionSchemeAttr("none")
    set_class_label(m.GetPrim(), label)
    return m


def _grid(nx, ny, x0, x1, z0, z1, y):
    xs, zs = np.linspace(x0, x1, nx + 1), np.linspace(z0, z1, ny + 1)
    pts = np.array([(x, y, z) for z in zs for x in xs])
    faces = [[j * (nx + 1) + i, j * (nx + 1) + i + 1, (j + 1) * (nx + 1) + i + 1, (j + 1) * (nx + 1) + i] for j in range(ny) for i in range(nx)]
    return pts, faces


def _render(tmp_path, stage_path, frames="1-3", *extra):
    import subprocess
    import sys

    out = tmp_path / "out"
    res = subprocess.run([sys.executable, "-m", "lfusd", "render-video", str(stage_path), "-o", str(out), "--samples", "1",
                          "--device", "cpu", "--frames", frames, *extra], capture_output=True, text=True)
    assert res.returncode == 0, res.stderr
    return out, res.stderr


def test_static_thin_pole_has_zero_flow_and_verify_passes(tmp_path):
    stage = new_stage(tmp_path / "pole.usda", 1, 3)
    _mesh(stage, "/World/Wall", *_grid(1, 1, -4, 4, -1, 4, 3.0), "wall")
    # a pole 3 cm wide (half a pixel) and 3 m tall: two sliver triangles, 100:1
    _mesh(stage, "/World/Pole", [(-0.27, 0.0, 0.0), (-0.24, 0.0, 0.0), (-0.24, 0.0, 3.0), (-0.27, 0.0, 3.0)], [[0, 1, 2], [0, 2, 3]], "pole")
    mover = _mesh(stage, "/World/Box", *_grid(2, 2, 0.2, 0.8, 0.5, 1.1, 1.0), "box")
    op = mover.AddTranslateOp()
    for f in (1, 2, 3):
        op.Set(Gf.Vec3d(0.1 * f, 0, 0), f)
    add_rig(stage, RIG)
    stage.Save()
    out, _ = _render(tmp_path, tmp_path / "pole.usda", "1-3", "--verify")
    ds = Dataset(out)
    # render-video --verify leaves verify's figures in the manifest: the dataset carries its proof
    cert = ds.manifest["certificate"]["main"]
    assert cert["ok"] and cert["unchecked"] == 0
    from lfusd.data.certificate import certified

    assert certified(out) == {"main": cert}  # bound to the rendered content, and the binding holds (issue 39 item 4)
    for key in ("depth", "instance", "flow_fwd", "flow_bwd", "scene_flow", "occlusion_fwd", "occlusion_bwd"):
        assert cert["keys"][key]["count"] > 0 and cert["keys"][key]["over"] == 0, key
    assert cert["keys"]["depth"]["coverage"] >= 0.99
    pole = [i for i, o in ds.objects.items() if o.label == "pole"][0]
    box = [i for i, o in ds.objects.items() if o.label == "box"][0]
    seen = 0
    for f in (1, 2, 3):
        for v in ds.views:
            inst = ds.read(f, v, "instance")
            static = (inst != box) & (inst > 0)
            seen += int((inst == pole).sum())
            for key, valid in (("flow_fwd", "valid_fwd"), ("flow_bwd", "valid_bwd")):
                sel = static & ds.read(f, v, valid)
                assert np.abs(ds.read(f, v, key)[sel]).max(initial=0) == 0, (f, v, key)
            assert (ds.read(f, v, "scene_flow")[static & ds.read(f, v, "valid_fwd")] == 0).all()
    assert seen > 20, "the pole must be in view"
    report = verify_dataset(ds)
    assert report.ok, report.failures()


def test_vertex_reordering_mesh_is_flagged_not_labelled(tmp_path):
    stage = new_stage(tmp_path / "reorder.usda", 1, 3)
    _mesh(stage, "/World/Wall", *_grid(1, 1, -4, 4, -1, 4, 3.0), "wall")
    pts, faces = _grid(4, 3, -0.8, 0.4, 0.4, 1.4, 0.5)
    sheet = _mesh(stage, "/World/Cache", pts, faces, "cloth")
    rng = np.random.default_rng(1)
    for f in (1, 2, 3):
        # the same surface moving right, its vertices written in another order at each frame
        perm = np.arange(len(pts)) if f == 1 else rng.permutation(len(pts))
        inv = np.argsort(perm)
        moved = pts + np.array([0.05 * f, 0, 0])
        sheet.GetPointsAttr().Set(Vt.Vec3fArray([Gf.Vec3f(*map(float, p)) for p in moved[perm]]), f)
        sheet.GetFaceVertexIndicesAttr().Set([int(inv[i]) for fc in faces for i in fc], f)
    add_rig(stage, RIG)
    stage.Save()
    out, err = _render(tmp_path, tmp_path / "reorder.usda")
    assert sum("/World/Cache" in ln and "topology" in ln for ln in err.splitlines()) == 1, err
    ds = Dataset(out)
    cloth = [i for i, o in ds.objects.items() if o.label == "cloth"][0]
    n = 0
    for f in (1, 2, 3):
        for v in ds.views:
            on = ds.read(f, v, "instance") == cloth
            n += int(on.sum())
            for sfx in ("fwd", "bwd"):
                assert not ds.read(f, v, f"valid_{sfx}")[on].any(), (f, v, sfx)
                assert (ds.read(f, v, f"flow_{sfx}")[on] == 0).all()
            wall = ds.read(f, v, "instance") > 0
            wall &= ~on
            if f < 3:
                assert ds.read(f, v, "valid_fwd")[wall].all()
    assert n > 50
    report = verify_dataset(ds)
    assert report.ok, report.failures()


def test_gltf_shaped_animated_assets_pass_verify_with_occlusion_at_96x96(tmp_path):
    """A Y-up centimetre stage as a glTF converter writes it: a panel animated by keyed translate +
    orient (quaternion) under a rotateX prim, passing in front of a glTF-shaped skinned character
    (numbered joints, Y-up centimetres, rotation above the SkelRoot) that walks; at 96x96 verify
    compares every pixel, occlusion included, at default limits."""
    from pxr import Gf, UsdGeom

    from support.characters import gltf_numbered
    from support.wild import render_and_verify

    from lfusd.cli import main

    char = tmp_path / "cesium" / "man.usda"
    char.parent.mkdir()
    gltf_numbered(char)
    path = tmp_path / "stage.usda"
    stage = new_stage(path, 1, 12)
    UsdGeom.SetStageUpAxis(stage, UsdGeom.Tokens.y)
    UsdGeom.SetStageMetersPerUnit(stage, 0.01)
    _mesh(stage, "/World/Ground", [(-1000, 0, -1000), (-1000, 0, 1000), (1000, 0, 1000), (1000, 0, -1000)], [[0, 1, 2, 3]], "ground")
    UsdGeom.Xform.Define(stage, "/World/Node").AddRotateXOp().Set(-90.0)  # a converter's axis fix
    panel = _mesh(stage, "/World/Node/Panel", *_grid(2, 2, -20, 20, -20, 20, 0), "box")  # vertical once under Node
    t, q = panel.AddTranslateOp(), panel.AddOrientOp()
    for f in range(1, 13):
        t.Set(Gf.Vec3d(-160 + 15 * f, -60, 100), f)  # stage: x, in front of the walker (z 60 cm), 1 m up
        a = 0.04 * f
        q.Set(Gf.Quatf(float(np.cos(a)), 0.0, 0.0, float(np.sin(a))), f)
    rig = RigSpec(name="main", rows=2, cols=2, width=96, height=96, baseline=0.05, at=(-0.6, 1.2, 3.5), look_at=(-0.6, 0.8, 0.0))
    add_rig(stage, rig)
    stage.GetRootLayer().Save()
    assert main(["animate", "add-person", str(path), "--path", "-1,0", "1,0", "--character", str(char)]) == 0
    ds, reports = render_and_verify(path, tmp_path / "out", "--frames", "5-8")
    report = next(iter(reports.values()))
    rows = {e["key"]: e for e in report.summary() if e["label"] == "(all)"}
    for key in ("occlusion_fwd", "occlusion_bwd", "flow_fwd", "depth"):
        assert rows[key]["coverage"] >= 0.99 and rows[key]["over"] == 0, (key, rows[key])
    labels = {ds.objects[i].label for f in ds.frames for v in ds.views for i in np.unique(ds.read(f, v, "instance")) if i}
    assert {"box", "person", "ground"} <= labels, labels
    occluded = sum(int(ds.read(f, v, "occlusion_fwd").sum()) for f in ds.frames[:-1] for v in ds.views)
    assert occluded > 20, "the panel must hide part of the scene as it moves"

"""Issue 25 item 3's acceptance: a catalogue of user assets shaped like real ones (a Y-up centimetre
.usdc car with instanced wheels and a foreign textured material, a .usdz tree with point-instanced
leaves; no lights) appears in a generated street, `lfusd check` passes, and a tiny render-video
(2x2 views, 48x48, 3 frames) of a rig looking at a catalogue car passes `lfusd verify`; the car's
pixels carry its instance id and its texture's red."""

from __future__ import annotations

import numpy as np
import pytest
from support.catalogue_assets import write_car, write_tree
from support.cli import run_cli
from support.wild import STATIC_KEYS, render_and_verify

from lfusd.camera import RigSpec

pytestmark = pytest.mark.render


def test_catalogue_assets_in_a_generated_street_render_and_verify(tmp_path, capsys):
    from lfusd.author.geometry import StageGeometry
    from lfusd.author.labels import object_table
    from lfusd.author.rigs import add_rig
    from lfusd.author.stage import open_stage
    from lfusd.author.vocabulary import ASSET

    lib = tmp_path / "library"
    write_car(lib)
    write_tree(lib)
    assert run_cli(capsys, "assets", "add", lib)[0] == 0
    path = tmp_path / "street.usda"
    code, _, err = run_cli(capsys, "stage", "new", "street", "-o", path, "--seed", "1", "--frames", "3", "--rigs", "0",
                           "--catalogue", lib / "catalogue.json")
    assert code == 0, err
    stage = open_stage(path)
    cars = [o for o in object_table(stage)[0] if o.label == "car" and stage.GetPrimAtPath(o.prim_path).HasAttribute(ASSET)]
    assert cars and any(o.label == "tree" and stage.GetPrimAtPath(o.prim_path).HasAttribute(ASSET)
                        for o in object_table(stage)[0])
    # a rig 7 m from the first catalogue car, looking at its middle from the road's centre line side
    geo = StageGeometry(stage)
    pts = np.concatenate([geo.mesh(p, 1).vertices for p in geo.parts_of(cars[0].prim_path)])
    centre = (pts.min(0) + pts.max(0)) / 2
    at = centre + np.array([0.0, -7.0 if centre[1] > 0 else 7.0, 1.5])
    add_rig(stage, RigSpec(name="rig_00", rows=2, cols=2, width=48, height=48, baseline=0.05,
                           at=tuple(float(v) for v in at), look_at=tuple(float(v) for v in centre)))
    stage.GetRootLayer().Save()
    code, out, err = run_cli(capsys, "check", path, "--no-coverage")
    assert code == 0 and "all constraints hold" in out, out + err
    ds, _ = render_and_verify(path, tmp_path / "out", "--frames", "1-3", keys=STATIC_KEYS)
    ids = [i for i, o in ds.objects.items() if o.prim_path == cars[0].prim_path]
    assert len(ids) == 1
    for view in ds.views:
        mask = ds.read(1, view, "instance") == ids[0]
        assert mask.sum() >= 40, view  # the car fills a good part of the view
        r, g, b = ds.read(1, view, "rgb")[mask][..., :3].astype(float).mean(axis=0)
        # the body's texture is red (180, 30, 30; stripes darker): lit and shaded, far redder than green or blue
        assert r > 1.5 * max(g, b), (view, r, g, b)

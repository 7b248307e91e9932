"""Issue 25 item 3's acceptance: a catalogue of user assets shaped like real ones (a Y-up centimetre
.usdc car with instanced wheels and a foreign textured material, a .usdz tree with point-instanced
leaves; no lights) appears in a generated street, `lfusd check` passes, and a tiny render-video
(2x2 views, 48x48, 3 frames) of two rigs, one looking at a catalogue car, one at a catalogue
tree, passes `lfusd verify`; each asset's pixels carry its one instance id, the car's its texture's red."""

from __future__ import annotations

import numpy as np
import pytest
from support.catalogue_assets import write_car, write_tree
from support.cli import run_cli
from support.wild import STATIC_KEYS

from lfusd import Dataset
from lfusd.camera import RigSpec
from lfusd.cli import main

pytestmark = pytest.mark.render


def test_catalogue_assets_in_a_generated_street_render_and_verify(tmp_path, capsys):
    from lfusd.author.geometry import StageGeometry
    from lfusd.author.labels import object_table
    from lfusd.author.rigs import add_rig
    from lfusd.author.stage import open_stage
    from lfusd.author.vocabulary import ASSET
    from lfusd.truth.verify import verify

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
    trees = [o for o in object_table(stage)[0] if o.label == "tree" and stage.GetPrimAtPath(o.prim_path).HasAttribute(ASSET)]
    assert cars and trees
    # rig_00 7 m from the first catalogue car, rig_01 9 m from the first catalogue tree, each looking
    # at the middle of its object's box from the road's side
    geo = StageGeometry(stage)
    for k, (obj, dist) in enumerate(((cars[0], 7.0), (trees[0], 9.0))):
        pts = np.concatenate([geo.mesh(p, 1).vertices for p in geo.parts_of(obj.prim_path)])
        centre = (pts.min(0) + pts.max(0)) / 2
        at = centre + np.array([0.0, -dist if centre[1] > 0 else dist, 1.0])
        add_rig(stage, RigSpec(name=f"rig_{k:02d}", rows=2, cols=2, width=48, height=48, baseline=0.05,
                               at=tuple(float(v) for v in at), look_at=tuple(float(v) for v in centre)))
    stage.GetRootLayer().Save()
    code, out, err = run_cli(capsys, "check", path, "--no-coverage")
    assert code == 0 and "all constraints hold" in out, out + err
    # support.wild.render_and_verify's run, for a stage of two rigs
    assert main(["render-video", str(path), "-o", str(tmp_path / "out"), "--rig", "all", "--frames", "1-3", "--samples", "1",
                 "--device", "cpu", "--quiet"]) == 0
    reports = verify(tmp_path / "out")
    assert sorted(reports) == ["rig_00", "rig_01"]
    for name, report in reports.items():
        assert all(report.compared().get(key, 0) > 0 for key in STATIC_KEYS), (name, report.compared())
        assert report.ok, f"rig {name}: " + "; ".join(report.failures()[:5]) + "\n" + report.table()
    for rig, obj, share in (("rig_00", cars[0], 40), ("rig_01", trees[0], 40)):
        ds = Dataset(tmp_path / "out", rig=rig)
        ids = [i for i, o in ds.objects.items() if o.prim_path == obj.prim_path]
        assert len(ids) == 1  # one object: the wheels' instances and the leaves' point instances are its parts
        for view in ds.views:
            mask = ds.read(1, view, "instance") == ids[0]
            assert mask.sum() >= share, (rig, view)  # the asset fills a good part of the view
            if rig == "rig_00":
                r, g, b = ds.read(1, view, "rgb")[mask][..., :3].astype(float).mean(axis=0)
                # the body's texture is red (180, 30, 30; stripes darker): lit and shaded, far redder than green or blue
                assert r > 1.5 * max(g, b), (view, r, g, b)


def test_a_dynamic_street_from_catalogues_walks_their_character_and_verifies(tmp_path, capsys):
    """--dynamic with catalogues of a car and a glTF-converted character (Y-up centimetres, numbered
    joints, a rotation above its SkelRoot, textured): the rig the choreography places watches a
    performer who is the catalogue's character; a tiny render-video (2x2 views, 48x48, 3 frames)
    passes `lfusd verify` on every motion key, and the character is one object in every view."""
    from support.characters import gltf_numbered
    from support.wild import render_and_verify

    from lfusd.author.catalogue import add_assets
    from lfusd.author.labels import object_table
    from lfusd.author.scenes import generate

    write_car(tmp_path / "cars")
    gltf_numbered(tmp_path / "people" / "man.usda")
    cats = [add_assets(tmp_path / "cars")[0], add_assets(tmp_path / "people", cls="person")[0]]
    path = tmp_path / "street.usda"
    stage = generate("street", path, 2, frames=3, rigs=1, grid=(2, 2), resolution=(48, 48), dynamic=True, catalogues=cats)
    people = [o.prim_path for o in object_table(stage)[0] if o.label == "person"]
    assert people and all(r.assetPath.endswith("man.usda") for p in people
                          for r in stage.GetPrimAtPath(p).GetMetadata("references").GetAddedOrExplicitItems())
    ds, _ = render_and_verify(path, tmp_path / "out", "--frames", "1-3")
    ids = {i for i, o in ds.objects.items() if o.prim_path in people}
    for view in ds.views:
        seen = np.isin(ds.read(2, view, "instance"), list(ids))
        assert seen.sum() >= 40, (view, seen.sum())  # the performer fills a good part of the view

"""Why Infinigen's assets rendered very dark through lfusd, proved on a test-authored asset in
Infinigen's export shape (tests/support/infinigen_assets.py), rendered tiny (64x48, 1 view):

1. its export carries Blender's world as a DomeLight of radiance 0.05: a stage holding the asset
   has a light, so lfusd adds no light of its own, and the asset is lit by that dome alone;
2. under the same light, its baked roughness/metallic/normal textures read as sRGB and its normal
   map without scale/bias (Blender's importer makes every normal map a Normal Map node, so the
   sRGB decode of the flat (0.5, 0.5, 1) tilts every normal about 40 degrees) shade it darker
   than the same asset with plain materials.

After lfusd.author.bake.clean_asset the asset is as bright as its plain twin: per object, the
mean linear RGB over its pixels (instance mask) within 10 %."""

from __future__ import annotations

import numpy as np
import pytest
from pxr import Gf, UsdGeom, UsdLux, UsdSemantics
from support.infinigen_assets import write_infinigen_table

from lfusd import Dataset
from lfusd.camera import RigSpec
from lfusd.cli import main

pytestmark = pytest.mark.render


def _stage(path, asset, lights: bool):
    """A stage holding ``asset`` at the origin as one labelled copy, seen by a 1-view 64x48 rig;
    ``lights``: a grey sky and a sun 50 degrees up (the asset's own lights switched off, as a
    catalogue placement does), else none (lfusd adds its neutral light only to a stage with none)."""
    from lfusd.author.rigs import add_rig
    from lfusd.author.stage import new_stage

    stage = new_stage(path)
    prim = UsdGeom.Xform.Define(stage, "/World/Table")
    prim.GetPrim().GetReferences().AddReference(str(asset))
    UsdSemantics.LabelsAPI.Apply(prim.GetPrim(), "class").CreateLabelsAttr().Set(["table"])
    if lights:
        dome = UsdLux.DomeLight.Define(stage, "/World/Sky")
        dome.CreateColorAttr(Gf.Vec3f(0.25, 0.25, 0.25))
        sun = UsdLux.DistantLight.Define(stage, "/World/Sun")
        sun.CreateIntensityAttr(3.0)
        sun.CreateNormalizeAttr(True)  # as lfusd's templates author their sun
        sun.CreateAngleAttr(0.53)
        sun.AddRotateXYZOp().Set(Gf.Vec3f(40.0, 0.0, 30.0))
        light = stage.GetPrimAtPath("/World/Table/env_light")
        if light:
            light.SetActive(False)
    add_rig(stage, RigSpec(name="rig", rows=1, cols=1, width=64, height=48, baseline=0.05,
                           at=(0.4, -2.4, 1.8), look_at=(0.0, 0.0, 0.45)))
    stage.GetRootLayer().Save()


def _brightness(out) -> float:
    """Mean linear RGB over the table's pixels (its instanced legs and twigs are objects of their own here)."""
    ds = Dataset(out)
    view = ds.views[0]
    inst, rgb = ds.read(1, view, "instance"), ds.read(1, view, "rgb_linear")
    ids = [i for i, o in ds.objects.items() if (o.prim_path + "/").startswith("/World/Table/")]
    mask = np.isin(inst, ids)
    assert mask.sum() >= 200, mask.sum()  # the table fills a good part of the 64x48 view
    return float(rgb[mask].mean())


@pytest.fixture(scope="module")
def rendered(tmp_path_factory):
    from lfusd.author.bake import clean_asset

    tmp = tmp_path_factory.mktemp("bake_render")
    raw = write_infinigen_table(tmp / "raw")
    plain = write_infinigen_table(tmp / "plain", plain=True)
    clean = tmp / "clean" / "table.usdc"
    clean_asset(raw, clean, cls="table")
    out = {}
    for name, asset, lights in (("raw", raw, True), ("clean", clean, True), ("plain", plain, True),
                                ("raw_unlit", raw, False), ("clean_unlit", clean, False)):
        _stage(tmp / f"{name}.usda", asset, lights)
        assert main(["render", str(tmp / f"{name}.usda"), "-o", str(tmp / f"{name}_out"), "--samples", "8", "--device", "cpu",
                     "--quiet"]) == 0
        out[name] = _brightness(tmp / f"{name}_out")
    print("mean linear RGB over the table:", {k: round(v, 4) for k, v in out.items()})
    return out


def test_clean_asset_is_as_bright_as_its_plain_twin_under_the_same_light(rendered):
    assert rendered["clean"] == pytest.approx(rendered["plain"], rel=0.10), rendered
    # as exported, the sRGB-read normal map (tilted normals) and the invisible glass make it far darker
    assert rendered["raw"] < 0.7 * rendered["plain"], rendered


def test_the_exported_dome_leaves_the_asset_unlit_and_clean_up_removes_it(rendered):
    # in a stage without lights of its own: the raw asset's dome is a light, so lfusd adds none and
    # the dome's 0.05 grey lights it; the cleaned asset has none and gets lfusd's neutral sky and sun
    assert rendered["raw_unlit"] < 0.2 * rendered["clean_unlit"], rendered

"""`--light`: the request's check, the parent's light detection and warnings, the work unit and
the manifest settings (pxr only, no Blender)."""

from __future__ import annotations

import json
import logging
from pathlib import Path

import pytest
from pxr import UsdGeom, UsdLux

from lfusd.author.stage import new_stage
from lfusd.errors import LfusdError
from lfusd.render import job
from lfusd.render.plan import Plan, StageSetup, WorkUnit, plan_units
from lfusd.render.request import RenderRequest


def request(**kw) -> RenderRequest:
    return RenderRequest(stage=Path("s.usda"), out=Path("out"), **kw)


def test_light_defaults_to_auto_and_refuses_other_values_on_one_line():
    assert request().light == "auto"
    request(light="none").check()
    with pytest.raises(LfusdError, match="unknown --light 'sun'; use one of auto, none") as e:
        request(light="sun").check()
    assert "\n" not in str(e.value)


def stage_with(tmp_path, add=None):
    stage = new_stage(tmp_path / "s.usda")
    UsdGeom.Mesh.Define(stage, "/World/Ground")
    if add:
        add(stage)
    return stage


def _instanced_light(stage):
    stage.CreateClassPrim("/Proto")  # abstract: only the instance proxy is a light on the stage
    UsdLux.SphereLight.Define(stage, "/Proto/Lamp")
    ref = stage.DefinePrim("/World/LampInstance")
    ref.GetReferences().AddInternalReference("/Proto")
    ref.SetInstanceable(True)


def _inactive_light(stage):
    UsdLux.DistantLight.Define(stage, "/World/Sun").GetPrim().SetActive(False)


@pytest.mark.parametrize("add,lit", [
    (None, False),
    (lambda s: UsdLux.DistantLight.Define(s, "/World/Sun"), True),
    (lambda s: UsdLux.DomeLight.Define(s, "/World/Sky"), True),
    (lambda s: UsdLux.MeshLightAPI.Apply(UsdGeom.Mesh.Define(s, "/World/Panel").GetPrim()), True),
    (_instanced_light, True),
    (_inactive_light, False),
])
def test_has_lights_sees_every_usdlux_light(tmp_path, add, lit):
    assert job.has_lights(stage_with(tmp_path, add)) is lit


@pytest.fixture
def warnings(caplog, monkeypatch):
    monkeypatch.setattr(logging.getLogger("lfusd"), "propagate", True)  # the CLI turns it off
    caplog.set_level(logging.WARNING, logger="lfusd.render.job")
    return caplog


def test_a_stage_without_lights_warns_once_and_auto_adds_light(tmp_path, warnings):
    dark = stage_with(tmp_path)
    assert job._add_light(request(), dark) is True
    assert [r.getMessage() for r in warnings.records] == [
        "stage s.usda has no lights; lfusd adds a neutral sky and sun (--light none to keep it dark)"]
    warnings.clear()
    assert job._add_light(request(light="none"), dark) is False
    assert [r.getMessage() for r in warnings.records] == [
        "stage s.usda has no lights and --light none: it renders black (--light auto adds a neutral sky and sun)"]


def test_a_stage_with_lights_is_untouched(tmp_path, warnings):
    lit = stage_with(tmp_path, lambda s: UsdLux.DistantLight.Define(s, "/World/Sun"))
    assert job._add_light(request(), lit) is False and job._add_light(request(light="none"), lit) is False
    assert warnings.records == []


def test_work_units_carry_add_light_and_settings_record_the_choice(tmp_path):
    req = request(light="none")
    plan = Plan(tmp_path, {"main": [(0, 0)]}, [1])
    units = plan_units(req, plan, {"main": {(0, 0): "/Rigs/main/cam_00_00"}}, {"main": (8, 8)},
                       StageSetup({}, [], False, [1, 1], True, {}))
    assert [u.add_light for u in units] == [True]
    assert WorkUnit.from_json(json.loads(json.dumps(units[0].to_json()))).add_light is True
    assert job._settings(req, {}, [])["light"] == "none"


def test_sunny_generated_scenes_ask_for_the_physical_sky_and_work_units_carry_it(tmp_path):
    from pxr import Usd

    from lfusd.author.vocabulary import LIGHTING

    stages = Path(__file__).resolve().parents[2] / "stages"
    for path in sorted(stages.glob("*_0*.usda")):
        stage = Usd.Stage.Open(str(path))
        sunny = stage.GetDefaultPrim().GetCustomDataByKey(LIGHTING)["setup"] == "sun"
        assert job.physical_sky(stage) is sunny, path.name
    plan = Plan(tmp_path, {"main": [(0, 0)]}, [1])
    units = plan_units(request(), plan, {"main": {(0, 0): "/Rigs/main/cam_00_00"}}, {"main": (8, 8)},
                       StageSetup({}, [], True, [1, 1], False, {}, True))
    assert WorkUnit.from_json(json.loads(json.dumps(units[0].to_json()))).physical_sky is True

"""One vocabulary (lfusd.author.vocabulary) and one rule registry (lfusd.author.rules.rule)."""

from __future__ import annotations

import ast
import inspect
from pathlib import Path

import pytest
from pxr import Gf, Usd, UsdGeom

import lfusd
import lfusd.author.rules as rules
from lfusd import LfusdError
from lfusd.author import vocabulary as vocab
from lfusd.author.labels import object_table, set_class_label
from lfusd.author.people import SupportSurfaces, person_surfaces
from lfusd.author.scenes import TEMPLATE_RULES, TEMPLATES

CLASS_KINDS = ("on", "not_on", "floats_on", "no_interpenetration")  # rules whose values are classes
STAGES = Path(__file__).resolve().parents[2] / "stages"


def _classes_named(rulebook: dict) -> set[str]:
    out = set()
    for key, table in rulebook.items():
        out.add(key)
        for kind in CLASS_KINDS:
            out.update(table.get(kind, ()))
    return out


def test_class_groups_are_disjoint_and_surfaces_are_ground_and_water():
    assert not set(vocab.GROUND) & set(vocab.WATER)
    assert vocab.SURFACES == set(vocab.GROUND) | set(vocab.WATER)
    assert not vocab.SURFACES & set(vocab.OBJECTS) and vocab.ANY not in vocab.CLASSES
    assert len(set(vocab.GROUND + vocab.WATER + vocab.OBJECTS)) == len(vocab.GROUND + vocab.WATER + vocab.OBJECTS)


def test_every_class_named_in_rules_people_and_templates_comes_from_the_vocabulary():
    known = vocab.CLASSES | {vocab.ANY}
    assert _classes_named(rules.DEFAULT_RULES) <= known, _classes_named(rules.DEFAULT_RULES) - known
    assert _classes_named(TEMPLATE_RULES) <= known, _classes_named(TEMPLATE_RULES) - known
    for t in TEMPLATES.values():
        assert _classes_named(t.rules) | t.labels | t.movers <= known, t.name
    # the person rule and the placement of people read the same groups
    assert rules.DEFAULT_RULES["person"]["on"] == list(vocab.GROUND)
    assert rules.DEFAULT_RULES["person"]["not_on"] == list(vocab.WATER)
    assert person_surfaces(Usd.Stage.CreateInMemory()) == (vocab.GROUND, vocab.WATER)
    defaults = inspect.signature(SupportSurfaces).parameters
    assert (defaults["support"].default, defaults["water"].default) == (vocab.GROUND, vocab.WATER)
    # and every class a generated stage carries is known
    generated = [Usd.Stage.Open(str(p)) for p in sorted(STAGES.glob("*.usda"))]
    generated = [s for s in generated if s.GetDefaultPrim().GetCustomDataByKey(vocab.TEMPLATE)]
    assert len(generated) >= 4
    for stage in generated:
        labels = {o.label for o in object_table(stage)[0]}
        assert labels <= known, (stage.GetRootLayer().identifier, labels - known)


def test_no_module_spells_an_lfusd_property_name_but_the_vocabulary():
    # String constants "lfusd:..." without spaces are property or metadata names; messages have spaces.
    root = Path(lfusd.__file__).parent
    found = []
    for py in sorted(root.rglob("*.py")):
        if py.name == "vocabulary.py":
            continue
        for node in ast.walk(ast.parse(py.read_text())):
            if isinstance(node, ast.Constant) and isinstance(node.value, str):
                if node.value.startswith("lfusd:") and not any(c.isspace() for c in node.value):
                    found.append(f"{py.relative_to(root)}:{node.lineno}: {node.value}")
    assert found == []


def test_property_names_keep_the_names_files_already_carry():
    assert vocab.rig_attr("focal_length_mm") == "lfusd:rig:focal_length_mm" and vocab.RIG_VIEW == "lfusd:rig:view"
    assert vocab.rule_attr("person", "on") == "lfusd:rule:person:on"
    assert vocab.constraint_attr("draft") == "lfusd:constraint:draft"
    assert (vocab.BOUNDS, vocab.WHEEL_RADIUS) == ("lfusd:bounds", "lfusd:wheelRadius")
    assert (vocab.TEMPLATE, vocab.SEED, vocab.DYNAMIC) == ("lfusd:template", "lfusd:seed", "lfusd:dynamic")
    assert (vocab.GAIT, vocab.SPEED, vocab.CYCLE_FRAMES, vocab.STRIDE) == (
        "lfusd:gait", "lfusd:speed", "lfusd:cycleFrames", "lfusd:stride")


def test_rule_kinds_come_from_the_registry_and_unknown_ones_are_refused_in_one_line():
    assert list(rules.RULES) == ["on", "not_on", "floats_on", "no_interpenetration", "inside", "in_bounds"]
    assert [k for k, r in rules.RULES.items() if r.pairwise] == ["no_interpenetration"]
    with pytest.raises(LfusdError) as e:
        rules._check_kind("hovers_over", "the test")
    assert str(e.value) == ("unknown rule 'hovers_over' in the test; known rules: on, not_on, floats_on, "
                            "no_interpenetration, inside, in_bounds, draft, tolerance")
    for taken in ("on", "draft"):
        with pytest.raises(LfusdError, match=f"^rule kind '{taken}' is taken"):
            rules.rule(taken)(lambda *a: None)
    assert list(rules.RULES)[-1] == "in_bounds"


def test_a_registered_rule_kind_is_read_and_evaluated(tmp_path, monkeypatch):
    monkeypatch.setattr(rules, "RULES", dict(rules.RULES))

    @rules.rule("taller_than")
    def taller_than(checker, i, r, scene, owner, frame):
        o = checker.objs[i]
        need = float(r.rules["taller_than"][0])
        return None if o.hi[2] - o.lo[2] > need else f"{o.hi[2] - o.lo[2]:.2f} m tall, not over {need:g} m"

    stage = Usd.Stage.CreateInMemory()
    UsdGeom.SetStageUpAxis(stage, UsdGeom.Tokens.z)
    UsdGeom.SetStageMetersPerUnit(stage, 1.0)
    stage.SetDefaultPrim(UsdGeom.Xform.Define(stage, "/World").GetPrim())
    for name, height, need in (("Short", 1.8, "2.0"), ("Tall", 1.8, "1.5")):
        x = UsdGeom.Xform.Define(stage, f"/World/{name}")
        cube = UsdGeom.Cube.Define(stage, f"/World/{name}/geo")
        cube.CreateSizeAttr(1.0)
        cube.AddScaleOp().Set(Gf.Vec3f(0.4, 0.4, height))
        set_class_label(x.GetPrim(), "statue")
        rules.set_constraint(x.GetPrim(), "taller_than", [need])
    assert [v.line() for v in rules.Checker(stage).check()] == [
        "/World/Short: taller_than broken at frame 1: 1.80 m tall, not over 2 m"]

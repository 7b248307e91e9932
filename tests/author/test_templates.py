"""The scene-template registry (lfusd.author.scenes.template): a template registers itself, its seed
key alone seeds it, and names and seed keys are unique."""

from __future__ import annotations

import pytest
from pxr import Usd

import lfusd.author.scenes as scenes
from lfusd import LfusdError, cli
from lfusd.author.labels import object_table
from lfusd.author.rules import Checker
from lfusd.author.scenes import GAP, TEMPLATE_RULES, Scene, Site, generate, template
from lfusd.author.scenes import objects as kit
from lfusd.author.scenes.build import box
from lfusd.author.vocabulary import rule_attr

SMALL = dict(frames=3, rigs=2, grid=(1, 1), resolution=(32, 32))


def plaza(scene: Scene) -> Site:
    """A throwaway template: a lawn with benches (classes and kit the library already has)."""
    rng = scene.rng
    scene.bounds = ((-10.0, -10.0), (10.0, 10.0))
    scene.add("/World/Lawn", "grass", [("surface", box((20.0, 20.0, 0.3), (0, 0, -0.15), tile=3.0), "grass")], track=False)
    for _ in range(3):
        parts = kit.bench(rng)
        pose = scene.place(parts, ((-8.0, -2.0), (8.0, 8.0)), GAP, margin=0.3)
        if pose:
            scene.add(scene.name("Bench"), "bench", parts, pose[0], pose[1])
    scene.builder.sun(float(rng.uniform(0, 360)), 45.0, 1.0)
    scene.builder.dome(0.5)
    return Site(lambda r: (r.uniform(-3, 3), r.uniform(-8, -6), 1.7), lambda r: (r.uniform(-2, 2), r.uniform(2, 4), 0.5))


def test_builtin_templates_keep_the_seed_keys_of_their_committed_stages():
    assert {n: t.seed_key for n, t in scenes.TEMPLATES.items()} == {"street": 0, "river": 1, "room": 2, "mixed": 3, "things": 4, "things_large": 5}
    assert all(t.build and t.animate and t.labels and t.movers for t in scenes.TEMPLATES.values())


def test_a_new_template_registered_first_changes_no_other_templates_stage(tmp_path, monkeypatch, capsys):
    builtin = list(scenes.TEMPLATES.values())
    before = {}
    for t in builtin:
        generate(t.name, tmp_path / "before" / f"{t.name}.usda", 5, **SMALL)
        before[t.name] = (tmp_path / "before" / f"{t.name}.usda").read_bytes()
    # A fresh registry: the new template first, the built-in ones after it in reverse order.
    registry: dict = {}
    monkeypatch.setattr(scenes, "TEMPLATES", registry)
    new = template("plaza", seed_key=99, labels={"grass", "bench"}, rules={"bench": {"on": ["grass"]}})(plaza)
    for t in reversed(builtin):
        registry[t.name] = t
    assert list(registry) == ["plaza", *reversed([t.name for t in builtin])]
    for t in builtin:
        generate(t.name, tmp_path / "after" / f"{t.name}.usda", 5, **SMALL)
        assert (tmp_path / "after" / f"{t.name}.usda").read_bytes() == before[t.name], t.name

    stage = generate("plaza", tmp_path / "plaza.usda", 5, **SMALL)
    assert new.labels <= {o.label for o in object_table(stage)[0]}
    assert [v.line() for v in Checker(stage).check()] == []
    assert stage.GetDefaultPrim().GetCustomDataByKey("lfusd:template") == "plaza"
    # its own rule overrides the library's in its stages only
    world = stage.GetDefaultPrim()
    assert list(world.GetAttribute(rule_attr("bench", "on")).Get()) == ["grass"]
    street = Usd.Stage.Open(str(tmp_path / "after" / "street.usda"))
    assert list(street.GetDefaultPrim().GetAttribute(rule_attr("bench", "on")).Get()) == TEMPLATE_RULES["bench"]["on"]
    # a different seed key is a different scene: the key, not the position, seeds it
    registry.pop("plaza")
    template("plaza", seed_key=98)(plaza)
    generate("plaza", tmp_path / "plaza98.usda", 5, **SMALL)
    assert (tmp_path / "plaza98.usda").read_bytes() != (tmp_path / "plaza.usda").read_bytes()

    with pytest.raises(LfusdError, match="template 'plaza' has no dynamic variant"):
        generate("plaza", tmp_path / "d.usda", 5, **SMALL, dynamic=True)
    # the command line offers what the registry holds
    assert cli.main(["stage", "templates"]) == 0
    assert capsys.readouterr().out.split() == list(registry) and "plaza" in registry
    assert cli.main(["stage", "new", "plaza", "-o", str(tmp_path / "cli.usda"), "--seed", "5", "--frames", "3",
                     "--rigs", "2", "--grid", "1x1", "--resolution", "32x32"]) == 0
    assert (tmp_path / "cli.usda").read_bytes() == (tmp_path / "plaza98.usda").read_bytes()


def test_a_duplicate_name_or_seed_key_is_refused(monkeypatch):
    names = list(scenes.TEMPLATES)
    registry = dict(scenes.TEMPLATES)
    monkeypatch.setattr(scenes, "TEMPLATES", registry)
    with pytest.raises(LfusdError, match="^template 'street' is registered twice"):
        template("street", seed_key=50)(plaza)
    with pytest.raises(LfusdError, match="^template 'plaza' has seed key 2, which template 'room' has"):
        template("plaza", seed_key=2)(plaza)
    for bad in (-1, 1.5, "7"):
        with pytest.raises(LfusdError, match="non-negative integer"):
            template("plaza", seed_key=bad)(plaza)
    assert list(registry) == names == ["street", "river", "room", "mixed", "things", "things_large"]  # nothing half-registered


def test_sun_colour_warms_towards_the_horizon():
    from lfusd.author.scenes.build import sun_color

    high, low = sun_color(75.0), sun_color(10.0)
    assert max(high) == max(low) == 1.0
    # blue is absorbed most along the longer path through air
    assert low[2] < high[2] < 1.0 and low[1] < high[1] and low[2] < low[1] < low[0]

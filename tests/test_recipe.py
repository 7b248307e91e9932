"""`lfusd dataset make`: the tiny recipe end to end (card, statistics against an independent count
on the rendered arrays), resume, and one-line errors for bad recipes."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from support.cli import assert_one_line_error, run_cli

from lfusd.data.dataset import Dataset
from lfusd.recipe import DISPARITY_EDGES, FLOW_EDGES, load_recipe, scene_specs

RECIPES = Path(__file__).resolve().parents[1] / "recipes"


def _counts(values: np.ndarray, edges) -> list[int]:
    """Pixels in [lo, hi) for each bin, one comparison per bin (independent of the library's search)."""
    return [int(((values >= lo) & (values < hi)).sum()) for lo, hi in zip(edges[:-1], edges[1:])]


@pytest.fixture(scope="module")
def made(tmp_path_factory):
    from lfusd.cli import main

    out = tmp_path_factory.mktemp("recipe") / "ds"
    code = main(["dataset", "make", str(RECIPES / "tiny.toml"), "-o", str(out), "--quiet"])
    return code, out


@pytest.mark.render
def test_tiny_recipe_writes_a_card_whose_statistics_match_the_rendered_arrays(made):
    code, out = made
    assert code == 0
    card = json.loads((out / "card.json").read_text())
    assert (out / "CARD.md").read_text().startswith("# Dataset card: tiny")
    for png in ("disparity", "flow", "coverage", "classes"):
        assert (out / "plots" / f"{png}.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    specs = scene_specs(load_recipe(RECIPES / "tiny.toml"))
    assert [s["name"] for s in card["scenes"]] == [s.name for s in specs] and len(specs) == 2
    assert card["verified"] and all(sum(s["compared"].values()) > 0 for s in card["scenes"])

    # Independently: disparity from the published definition d = f_px * b / z on the stored depth,
    # |flow_fwd| on valid pixels of frames with a next frame, classes from the semantic ids.
    disp, flow_mag, classes, moving, pixels = [], [], {}, [], 0
    for spec in specs:
        ds = Dataset(out / "scenes" / spec.name, rig="rig_00")
        fx = ds.intrinsics(ds.views[0])[0, 0]
        for f in ds.frames:
            for view in ds.views:
                z = np.asarray(ds.read(f, view, "depth"), np.float64)
                pixels += z.size
                disp.append(fx * ds.baseline / z[np.isfinite(z)])
                sem = np.asarray(ds.read(f, view, "semantic"))
                for cid in np.unique(sem):
                    classes[ds.classes[cid]] = classes.get(ds.classes[cid], 0) + int((sem == cid).sum())
                if spec.dynamic and f + 1 in ds.frames:
                    fl = np.asarray(ds.read(f, view, "flow_fwd"), np.float64)
                    valid = np.asarray(ds.read(f, view, "valid_fwd"), bool)
                    mag = np.sqrt(fl[..., 0] ** 2 + fl[..., 1] ** 2)
                    flow_mag.append(mag[valid])
                    moving.append(np.count_nonzero(valid & (mag > 0.01)) / valid.size)
    disp, flow_mag = np.concatenate(disp), np.concatenate(flow_mag)
    assert pixels == card["pixels"] == 4 * 32 * 32 * (1 + 3)  # 4 views: the still scene 1 frame, the video 3
    assert card["disparity"]["pixels"] == disp.size > 0
    assert card["disparity"]["min"] == pytest.approx(disp.min(), rel=1e-4)
    assert card["disparity"]["max"] == pytest.approx(disp.max(), rel=1e-4)
    # Bin counts of the stored disparity key agree with ours but for values within float error of an edge.
    near_edge = sum(int((np.abs(disp - e) <= 1e-4 * e).sum()) for e in DISPARITY_EDGES[1:-1])
    assert np.abs(np.subtract(card["disparity"]["counts"], _counts(disp, DISPARITY_EDGES))).sum() <= 2 * near_edge
    assert card["flow"]["pixels"] == flow_mag.size > 0
    assert card["flow"]["counts"] == _counts(flow_mag, FLOW_EDGES)
    assert sum(card["flow"]["counts"][1:]) > 0, "the tiny video's movers are in view"
    assert {k: v for k, v in card["classes"].items()} == {(k or "unlabelled"): v for k, v in classes.items()}
    assert card["coverage"]["frames"] == len(moving) == 2 * 4
    assert round(card["coverage"]["mean"], 6) == round(float(np.mean(moving)), 6)
    assert round(card["coverage"]["any"], 6) == round(float(np.mean(np.asarray(moving) > 0)), 6)


@pytest.mark.render
def test_a_rerun_skips_complete_verified_scenes_and_remakes_one_whose_record_is_gone(made, capsys):
    code, out = made
    assert code == 0
    records = sorted((out / "scenes").glob("*.json"))
    before = {p.name: p.read_text() for p in records}
    code, stdout, _ = run_cli(capsys, "dataset", "make", RECIPES / "tiny.toml", "-o", out, "--quiet")
    assert code == 0 and stdout.count("complete and verified, skipped") == 2 and "(0 made, 2 skipped)" in stdout
    assert {p.name: p.read_text() for p in records} == before
    records[0].unlink()
    code, stdout, _ = run_cli(capsys, "dataset", "make", RECIPES / "tiny.toml", "-o", out, "--quiet")
    assert code == 0 and "(1 made, 1 skipped)" in stdout
    # The remade scene's dataset was complete: its render resumed with nothing to do, its statistics are the same.
    assert json.loads(records[0].read_text())["stats"] == json.loads(before[records[0].name])["stats"]


BAD = [
    ("[dataset]\nname = 't'\ngrid = [2, 2]\nresolution = [32, 32]\n[[part]]\nname = 'a'\ntemplates = ['castle']\nscenes = 1\n",
     "part.a.templates", "castle"),
    ("[dataset]\nname = 't'\ngrid = [2, 2]\nresolution = [32, 32]\n[[part]]\nname = 'a'\ntemplates = ['room']\nscenes = 0\n",
     "part.a.scenes", "positive integer"),
    ("[dataset]\nname = 't'\ngrid = [2, 2]\nresolution = '32x32'\n[[part]]\nname = 'a'\ntemplates = ['room']\nscenes = 1\n",
     "dataset.resolution", "[WIDTH, HEIGHT]"),
    ("[dataset]\nname = 't'\ngrid = [2, 2]\nresolution = [32, 32]\n[[part]]\nname = 'a'\ntemplates = ['room']\nscenes = 1\nrigs = [3, 12]\n",
     "part.a.rigs", "1-10"),
    ("[dataset]\nname = 't'\ngrid = [2, 2]\nresolution = [32, 32]\nexecutor = 'slurm'\n[[part]]\nname = 'a'\ntemplates = ['room']\nscenes = 1\n",
     "dataset.executor", "local, ray"),
    ("[dataset]\nname = 't'\ngrid = [2, 2]\nresolution = [32, 32]\n[[part]]\nname = 'a'\ntemplates = ['room']\nscenes = 1\nframes = 1\ndynamic = true\n",
     "part.a.frames", "at least 2"),
    ("[dataset]\nname = 't'\ngrid = [2, 2]\nresolution = [32, 32]\n", "[[part]]", "add at least one"),
    # splits: a known name, all parts or none, no scene (template, seed) in two splits, held-out templates in test parts only
    ("[dataset]\nname = 't'\ngrid = [2, 2]\nresolution = [32, 32]\n[[part]]\nname = 'a'\ntemplates = ['room']\nscenes = 2\nfirst_seed = 0\nsplit = 'dev'\n", "part.a.split", "train, val, test"),
    ("[dataset]\nname = 't'\ngrid = [2, 2]\nresolution = [32, 32]\n[[part]]\nname = 'a'\ntemplates = ['room']\nscenes = 2\nfirst_seed = 0\nsplit = 'train'\n[[part]]\nname = 'b'\ntemplates = ['room']\nscenes = 2\nfirst_seed = 5\n", "part.b.split", "must be set when other parts"),
    ("[dataset]\nname = 't'\ngrid = [2, 2]\nresolution = [32, 32]\n[[part]]\nname = 'a'\ntemplates = ['room']\nscenes = 2\nfirst_seed = 0\nsplit = 'train'\n[[part]]\nname = 'b'\ntemplates = ['room', 'street']\nscenes = 2\nfirst_seed = 1\nsplit = 'test'\n", "part.b.first_seed",
     "out of part a (train): both make room seed 1"),
    ("[dataset]\nname = 't'\ngrid = [2, 2]\nresolution = [32, 32]\nheld_out = ['street']\n[[part]]\nname = 'a'\ntemplates = ['room', 'street']\nscenes = 2\nfirst_seed = 0\nsplit = 'train'\n[[part]]\nname = 'b'\ntemplates = ['street']\nscenes = 2\nfirst_seed = 9\nsplit = 'test'\n",
     "part.a.templates", "held-out template 'street' in a train part"),
    ("[dataset]\nname = 't'\ngrid = [2, 2]\nresolution = [32, 32]\nheld_out = ['street']\n[[part]]\nname = 'a'\ntemplates = ['room']\nscenes = 2\nfirst_seed = 0\n", "dataset.held_out", "needs parts with a split"),
    ("[dataset]\nname = 't'\ngrid = [2, 2]\nresolution = [32, 32]\nheld_out = ['mixed']\n[[part]]\nname = 'a'\ntemplates = ['room']\nscenes = 2\nfirst_seed = 0\nsplit = 'train'\n[[part]]\nname = 'b'\ntemplates = ['street']\nscenes = 2\nfirst_seed = 0\nsplit = 'test'\n", "dataset.held_out",
     "a test part uses"),
    ("[dataset]\nname = 't'\ngrid = [2, 2]\nresolution = [32, 32]\nheld_out = ['castle']\n[[part]]\nname = 'a'\ntemplates = ['room']\nscenes = 2\nfirst_seed = 0\nsplit = 'test'\n", "dataset.held_out", "must list templates"),
    ("[dataset\nname = 't'\n", "not valid TOML", "fix the syntax"),
]


@pytest.mark.parametrize("text,field,fix", BAD, ids=[b[1] for b in BAD])
def test_a_bad_recipe_errors_in_one_line_naming_the_field_and_the_fix(tmp_path, capsys, text, field, fix):
    recipe = tmp_path / "bad.toml"
    recipe.write_text(text)
    code, _, err = run_cli(capsys, "dataset", "make", recipe, "-o", tmp_path / "out")
    assert code == 2
    assert_one_line_error(code, err, field, fix)
    assert not (tmp_path / "out").exists(), "nothing is written for a bad recipe"


def test_the_committed_recipes_are_valid_and_the_default_has_the_papers_shape():
    tiny = scene_specs(load_recipe(RECIPES / "tiny.toml"))
    assert len(tiny) == 2 and {s.rigs for s in tiny} == {1} and max(s.frames for s in tiny) == 3
    default = scene_specs(load_recipe(RECIPES / "default.toml"))
    static = [s for s in default if not s.dynamic]
    assert len(static) == 50 and all(8 <= s.rigs <= 10 for s in static) and {s.rigs for s in static} == {8, 9, 10}
    assert all(s.frames == 150 for s in default if s.dynamic)
    assert len({s.name for s in default}) == len(default)


def test_the_training_recipes_have_disjoint_splits_and_a_template_held_out_for_test():
    for name, resolution in (("train_preview.toml", (128, 128)), ("train_full.toml", (512, 512))):
        recipe = load_recipe(RECIPES / name)
        assert recipe.grid == (9, 9) and recipe.resolution == resolution, name
        specs = scene_specs(recipe)
        scenes = {split: {(s.template, s.seed) for s in specs if s.split == split} for split in ("train", "val", "test")}
        assert all(scenes.values()) and {s.split for s in specs} == {"train", "val", "test"}, name
        assert not (scenes["train"] & scenes["val"] or scenes["train"] & scenes["test"] or scenes["val"] & scenes["test"]), name
        held = set(recipe.held_out)
        assert held and held <= {t for t, _ in scenes["test"]} and not held & {t for t, _ in scenes["train"] | scenes["val"]}, name
        assert {t for t, _ in scenes["train"]} <= {"things", "things_large"}, name
        assert all(s.dynamic and s.frames >= 2 for s in specs), name  # clips: scene flow trains on them too
        assert len({s.name for s in specs}) == len(specs), name


def test_split_scenes_lists_each_splits_verified_scene_folders(tmp_path):
    from lfusd.recipe import _spec_dict, split_scenes

    text = ("[dataset]\nname = 't'\ngrid = [2, 2]\nresolution = [32, 32]\nheld_out = ['street']\n"
            "[[part]]\nname = 'a'\ntemplates = ['room']\nscenes = 2\nsplit = 'train'\n"
            "[[part]]\nname = 'b'\ntemplates = ['room']\nscenes = 1\nfirst_seed = 5\nsplit = 'val'\n"
            "[[part]]\nname = 'c'\ntemplates = ['street']\nscenes = 2\nsplit = 'test'\n")
    (tmp_path / "recipe.toml").write_text(text)
    (tmp_path / "scenes").mkdir()
    specs = scene_specs(load_recipe(tmp_path / "recipe.toml"))
    assert [s.split for s in specs] == ["train", "train", "val", "test", "test"]
    for i, s in enumerate(specs):
        if i == 1:
            continue  # not made yet
        record = {"version": 1, "spec": _spec_dict(s), "verified": i != 4}  # the last one failed verification
        (tmp_path / "scenes" / f"{s.name}.json").write_text(json.dumps(record))
        (tmp_path / "scenes" / s.name).mkdir()
        (tmp_path / "scenes" / s.name / "manifest.json").write_text("{}")
    got = split_scenes(tmp_path)
    assert {k: [p.name for p in v] for k, v in got.items()} == {
        "train": ["a_000_room_s0"], "val": ["b_000_room_s5"], "test": ["c_000_street_s0"]}
    # a recipe without splits keeps its records' identity: no split field in them
    assert "split" not in _spec_dict(scene_specs(load_recipe(RECIPES / "tiny.toml"))[0])

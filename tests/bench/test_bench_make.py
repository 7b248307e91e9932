"""`lfusd bench make`: frozen definitions (disjoint splits, stage digests that catch a drift), and the
tiny benchmark's folder: public/ without the test ground truth, gt/ with digests, resume."""

from __future__ import annotations

import hashlib
import json
import tomllib

import numpy as np
import pytest

from support.cli import assert_one_line_error, run_cli

from lfusd.bench import make as bench_make
from lfusd.data.dataset import Dataset
from lfusd.data.formats import read_png


def test_every_definition_has_disjoint_train_val_test_scenes_and_a_digest_per_stage():
    assert {"tiny", "preview", "full"} <= set(bench_make.definition_names())
    for name in bench_make.definition_names():
        d = bench_make.load_definition(name)
        scenes = {p: {(s.template, s.seed) for s in d.split(p)} for p in bench_make.SPLITS}
        assert all(scenes.values()), name
        assert not (scenes["train"] & scenes["val"]) and not (scenes["train"] & scenes["test"]) and not (scenes["val"] & scenes["test"])
        assert set(d.digests) == {s.name for s in d.specs}, f"{name}: freeze it with scripts/bench_freeze.py"
        assert all(s.dynamic and s.frames >= 2 for s in d.specs)
    full = bench_make.load_definition("full").recipe
    assert full.grid == (9, 9) and full.resolution == (1024, 1024)
    assert all(p.frames == 150 for p in full.parts)


def test_a_definition_whose_parts_share_a_scene_is_refused(tmp_path, monkeypatch):
    text = (bench_make.DEFINITIONS / "tiny.toml").read_text().replace("first_seed = 2000", "first_seed = 1000")
    (tmp_path / "dup.toml").write_text(text)
    (tmp_path / "dup.digests.json").write_text('{"stages": {}}')
    monkeypatch.setattr(bench_make, "DEFINITIONS", tmp_path)
    with pytest.raises(bench_make.LfusdError, match="are the same scene"):
        bench_make.load_definition("dup")


def test_a_stage_that_differs_from_its_frozen_digest_is_refused_before_rendering(tmp_path, monkeypatch):
    d = bench_make.load_definition("tiny")  # its frozen digests hold for today's generators: the tiny_bench fixture's make checks them
    first = d.specs[0].name
    drifted = {**d.digests, first: "0" * 64}
    monkeypatch.setattr(bench_make, "load_definition", lambda name: bench_make.Definition(**{**d.__dict__, "digests": drifted}))
    with pytest.raises(bench_make.LfusdError, match=f"stage {first} of benchmark tiny differs from its frozen digest"):
        bench_make.make_bench("tiny", tmp_path / "b")
    assert not (tmp_path / "b").exists()  # a refused first run leaves nothing


def test_score_and_oracle_refuse_a_folder_that_is_not_a_finished_benchmark(tmp_path, capsys):
    (tmp_path / "sub").mkdir()
    code, _, err = run_cli(capsys, "bench", "score", tmp_path / "sub", "--bench", tmp_path)
    assert_one_line_error(code, err, "is not a benchmark folder", "lfusd bench make")
    (tmp_path / "bench.json").write_text(json.dumps({"format": "lfusd-bench", "name": "tiny", "complete": False}))
    code, _, err = run_cli(capsys, "bench", "oracle", tmp_path, "-o", tmp_path / "o")
    assert_one_line_error(code, err, "is not complete", "lfusd bench make tiny")


@pytest.mark.render
def test_tiny_bench_publishes_rgb_and_cameras_only_for_test_and_keeps_its_ground_truth_in_gt(tiny_bench):
    code, root = tiny_bench
    assert code == 0
    rec = json.loads((root / "bench.json").read_text())
    assert rec["complete"] and set(rec["splits"]) == {"train", "val", "test"}
    test = rec["splits"]["test"]
    for split in ("train", "val"):
        for scene in rec["splits"][split]:
            ds = Dataset(root / "public" / split / scene)
            assert np.asarray(ds.read(ds.frames[0], ds.views[0], "flow_fwd")).shape == (32, 32, 2)
    for scene in test:
        pub = root / "public" / "test" / scene
        files = sorted(p.relative_to(pub).as_posix() for p in pub.rglob("*") if p.is_file())
        gt = Dataset(root / "gt" / scene)
        want = ["cameras.json"] + sorted(f"rgb/{f:04d}_{v[0]:02d}_{v[1]:02d}.png" for f in gt.frames for v in gt.views)
        assert files == want
        cams = json.loads((pub / "cameras.json").read_text())
        for f in gt.frames:
            for v in gt.views:
                assert np.array_equal(read_png(pub / "rgb" / f"{f:04d}_{v[0]:02d}_{v[1]:02d}.png"), np.asarray(gt.read(f, v, "rgb")))
                assert np.allclose(cams["cam_to_world"][str(f)][f"{v[0]:02d}_{v[1]:02d}"], gt.cam_to_world(f, v))
        assert np.allclose(cams["intrinsics"], gt.intrinsics(gt.views[0])) and cams["scored_frames"] == gt.frames[:-1]
        # the published range holds every true disparity of the scene
        lo, hi = cams["disparity_range"]
        for f in gt.frames:
            for v in gt.views:
                d = np.asarray(gt.read(f, v, "disparity"))[np.isfinite(gt.read(f, v, "depth"))]
                assert lo <= d.min() and d.max() <= hi
    # no ground-truth file of a test scene anywhere under public/
    test_files = {hashlib.sha256(p.read_bytes()).hexdigest() for s in test for p in (root / "gt" / s).rglob("*") if p.is_file()
                  and p.suffix == ".exr"}
    assert test_files and not any(hashlib.sha256(p.read_bytes()).hexdigest() in test_files for p in (root / "public").rglob("*") if p.is_file())
    assert not any(s in p.as_posix() for s in test for p in (root / "public").rglob("*") if p.suffix in (".exr", ".json") and "test/" not in p.as_posix())
    # gt/digests.json: every file under gt/, checked independently
    digests = json.loads((root / "gt" / "digests.json").read_text())
    on_disk = {p.relative_to(root / "gt").as_posix() for p in (root / "gt").rglob("*") if p.is_file() and p.name != "digests.json"}
    assert set(digests) == on_disk
    assert all(hashlib.sha256((root / "gt" / k).read_bytes()).hexdigest() == v for k, v in digests.items())
    assert (root / "CARD.md").read_text().startswith("# Benchmark card: lfusd bench tiny")
    pub_card = (root / "public" / "CARD.md").read_text()
    assert pub_card.startswith("# Benchmark card") and "## Scenes" in pub_card
    shown = [s["name"] for s in json.loads((root / "public" / "card.json").read_text())["scenes"]]
    assert shown == rec["splits"]["train"] + rec["splits"]["val"]  # test statistics stay out of public/


@pytest.mark.render
def test_tiny_bench_rerun_resumes_and_another_definition_is_refused(tiny_bench, capsys):
    _, root = tiny_bench
    code, out, _ = run_cli(capsys, "bench", "make", "tiny", "-o", root, "--quiet")
    assert code == 0 and "(0 rendered, 3 skipped)" in out
    code, _, err = run_cli(capsys, "bench", "make", "full", "-o", root, "--quiet")
    assert_one_line_error(code, err, "another benchmark definition")


def test_the_definitions_are_recipes_lfusd_dataset_make_reads():
    from lfusd.recipe import parse_recipe

    for name in bench_make.definition_names():
        path = bench_make.DEFINITIONS / f"{name}.toml"
        assert parse_recipe(tomllib.loads(path.read_text()), str(path)).parts


def test_make_bench_passes_its_run_settings_to_every_scene_and_only_those(tmp_path, monkeypatch):
    """--executor/--workers/--device change how a scene renders (lfusd.recipe.RUN_SETTINGS), not its identity."""
    from lfusd import recipe

    seen = []

    def fake_scene(r, spec, root, quiet=True):
        seen.append((r.executor, r.ray_address, r.workers, r.device))
        raise bench_make.LfusdError("stopped by the test")

    monkeypatch.setattr(recipe, "make_scene", fake_scene)
    with pytest.raises(bench_make.LfusdError, match="stopped by the test"):
        bench_make.make_bench("tiny", tmp_path / "b", executor="ray", ray_address="host:1", workers=3, device="cpu")
    assert seen == [("ray", "host:1", 3, "cpu")]
    with pytest.raises(bench_make.LfusdError, match="cannot override samples"):
        recipe.make_dataset(tmp_path / "b" / "recipe.toml", tmp_path / "c", overrides={"samples": 1})

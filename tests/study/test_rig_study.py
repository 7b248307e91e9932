"""`lfusd rig-study`: candidates and shared cameras, scores on closed-form scenes, the command end to end.

The closed-form scenes are ray-cast here, from their definition: a textured wall z = WALL_Z
in front of cameras looking down +z (identity rotation, OpenCV axes), and optionally a small
textured card just in front of one camera, outside every other camera's view."""

from __future__ import annotations

import hashlib
import json
from pathlib import Path

import numpy as np
import pytest

from support.cli import assert_one_line_error, run_cli

from lfusd.camera import RigSpec, grid_offset
from lfusd.study.candidates import arrangements, build
from lfusd.study.score import PSNR_CAP, Bands, Views, estimate_inverse_depth, neighbours, parallax, redundancy, visibility

STAGES = Path(__file__).resolve().parents[2] / "stages"
H = W = 48
F_PX = 50.0
K = np.array([[F_PX, 0, (W - 1) / 2], [0, F_PX, (H - 1) / 2], [0, 0, 1.0]])
WALL_Z = 4.0
CARD_Z, CARD_HALF = 0.05, 0.04  # metres in front of its camera; half width (its camera's view is +-0.024 m there)


def _wall_rgb(x, y):
    return np.stack([0.5 + 0.35 * np.sin(2 * np.pi * x / 0.9) * np.cos(2 * np.pi * y / 0.7),
                     0.5 + 0.3 * np.cos(2 * np.pi * (x + y) / 1.1),
                     0.5 + 0.3 * np.sin(2 * np.pi * (x - 0.5 * y) / 0.8)], -1)


def _card_rgb(x, y):
    return np.stack([0.5 + 0.45 * np.sin(2 * np.pi * x / 0.012), 0.5 + 0.45 * np.cos(2 * np.pi * y / 0.01), 0.2 + 0 * x], -1)


def cast(centre, card_centre=None):
    """(rgb uint8, planar depth) of a camera at ``centre`` looking down +z: ray-plane intersections at pixel centres."""
    v, u = np.mgrid[0:H, 0:W].astype(np.float64)
    dx, dy = (u - K[0, 2]) / F_PX, (v - K[1, 2]) / F_PX  # ray direction with z = 1
    cx, cy, cz = centre
    t = WALL_Z - cz
    rgb, depth = _wall_rgb(cx + t * dx, cy + t * dy), np.full((H, W), t)
    if card_centre is not None:
        kx, ky, kz = card_centre
        tc = kz - cz
        x, y = cx + tc * dx, cy + tc * dy
        hit = (tc > 0) & (np.abs(x - kx) <= CARD_HALF) & (np.abs(y - ky) <= CARD_HALF)
        rgb = np.where(hit[..., None], _card_rgb(x, y), rgb)
        depth = np.where(hit, tc, depth)
    return np.clip(np.round(rgb * 255), 0, 255).astype(np.uint8), depth.astype(np.float32)


def views_of(centres, card_centre=None) -> Views:
    poses = np.stack([np.eye(4)] * len(centres))
    poses[:, :3, 3] = centres
    shots = [cast(c, card_centre) for c in centres]
    return Views(np.stack([s[0] for s in shots]), np.stack([s[1] for s in shots]), K, poses, {str(i): i for i in range(len(centres))})


GRID = RigSpec(rows=3, cols=3, width=W, height=H)
BANDS = Bands((1.0, 3.0, 10.0))


def grid_centres(b=0.1):
    return np.array([[(c - 1) * b, (r - 1) * b, 0.0] for r, c in GRID.views])


def held_out(views: Views):
    order = {v: k for k, v in enumerate(GRID.views)}
    groups = [[order[n] for n in neighbours(GRID, v)] for v in GRID.views]
    return redundancy(views, list(range(9)), groups, BANDS, device="cpu")


def test_a_duplicated_camera_is_the_most_redundant_view():
    centres = grid_centres()
    centres[5] = centres[4]  # view (1, 2) stands where the centre view stands
    r = held_out(views_of(centres))
    psnr = r["psnr_views"]
    others = [p for k, p in enumerate(psnr) if k not in (4, 5)]
    assert psnr[4] == psnr[5] == max(psnr) == PSNR_CAP, psnr
    assert max(others) < PSNR_CAP - 20, psnr  # the rest are reconstructed, not copied
    assert r["n_views_px"] == 9 * H * W


def test_a_view_whose_content_no_other_camera_sees_is_the_least_redundant():
    centres = grid_centres()
    card = centres[0] + np.array([0.0, 0.0, CARD_Z])  # fills view (0, 0); beyond every other camera's field of view
    views = views_of(centres, card)
    assert np.all(views.depth[0] < 0.1) and np.all(views.depth[1:] > 1.0)  # the scene is as intended
    r = held_out(views)
    psnr = r["psnr_views"]
    assert psnr[0] == min(psnr) and psnr[0] < sorted(psnr)[1] - 10, psnr
    vis = visibility(views, list(range(9)))
    assert vis["coverage_views"][0] == 0.0 and min(vis["coverage_views"][1:]) > 90.0, vis["coverage_views"]
    assert vis["n_visibility_px"] == 9 * H * W


def test_coverage_and_parallax_of_two_cameras_follow_the_shift_on_a_wall():
    dx = 0.12
    views = views_of(np.array([[0.0, 0.0, 0.0], [dx, 0.0, 0.0]]))
    shift = F_PX * dx / WALL_Z  # camera 1 sees the wall point of column u at u - shift
    vis = visibility(views, [0, 1])
    seen_cols = sum(1 for u in range(W) if 0 <= u - shift <= W - 1)
    assert vis["coverage_views"][0] == pytest.approx(100.0 * seen_cols / W, abs=1e-9)
    assert vis["holes"] == 0.0
    par = parallax(views, 0, [0, 1])
    assert par["parallax_nn"] == pytest.approx(shift, rel=1e-6) and par["n_parallax_px"] == H * W


def test_the_sweep_finds_the_wall():
    views = views_of(grid_centres(0.15))
    q = estimate_inverse_depth(views, 4, list(range(9)), device="cpu")
    rel = np.abs(q * WALL_Z - 1.0)
    inner = rel[8:-8, 8:-8]
    assert np.median(inner) < 0.02 and inner.size == (H - 16) * (W - 16), np.median(inner)


def test_candidates_share_cameras_by_rig_local_pose():
    base = RigSpec(width=64, height=64)
    arrs = arrangements([0.1], ["uniform", "linear"], ["plane"], ["parallel"])
    candidates, skipped, unions = build({"main": base}, arrs, (5, 5), (32, 32))
    # Offsets by the published definition: gap j is b (uniform) or j*b (linear), from the centre out.
    uni, lin = [-2, -1, 0, 1, 2], [-3, -1, 0, 1, 3]
    positions = {(x, y) for o in (uni, lin) for x in o for y in o}
    assert [grid_offset(i, 5, "linear") for i in range(5)] == lin
    assert len(candidates) == 2 and not skipped
    assert len(unions["main"].ids) == len(positions) == 41
    assert sum(len(c.cameras) for c in candidates) == 50
    # a sphere wider than a hemisphere (offsets to 3 gaps of 6 m on a 10 m radius: 1.8 rad) is reported, not studied
    arrs = arrangements([6.0], ["exponential"], ["plane", "sphere"], ["converge"])
    candidates, skipped, _ = build({"main": base}, arrs, (5, 5), (32, 32))
    assert [c.arrangement.layout for c in candidates] == ["plane"] and len(skipped) == 1


@pytest.mark.render
def test_rig_study_end_to_end_shares_renders_resumes_and_applies(capsys, tmp_path):
    from support.scenes import PLANE_RIG, write_box_stage

    from lfusd.author.rigs import rigs
    from lfusd.author.stage import open_stage

    stage = tmp_path / "boxes.usda"
    write_box_stage(stage, [PLANE_RIG])
    before = hashlib.sha256(stage.read_bytes()).hexdigest()
    out = tmp_path / "study"
    args = [stage, "-o", out, "--grid", "3x3", "--baselines", "0.05,0.4", "--spacing", "uniform,linear", "--layout", "plane",
            "--axes", "parallel", "--resolution", "32x32", "--samples", "2", "--device", "cpu", "--quiet"]
    code, stdout, err = run_cli(capsys, "rig-study", *args)
    assert code == 0, err
    # 4 candidates of 9 views; in a 3x3 grid uniform and linear spacing are the same cameras, and every baseline shares the centre.
    assert "4 candidates at 1 position(s): 36 views, 17 distinct cameras" in err
    manifest = json.loads((out / "renders" / "manifest.json").read_text())
    assert manifest["settings"]["rigs"]["study_main"]["cols"] == 17
    assert len(list((out / "renders" / "study_main" / "f000001").glob("00_*"))) == 17
    report = (out / "report.md").read_text()
    for name in ("b0p05_uniform_plane_parallel", "b0p4_linear_plane_parallel"):
        assert name in report and (out / "heatmaps" / f"{name}.png").is_file()
    assert (out / "score_vs_baseline.png").stat().st_size > 0
    scored = {p.name: p.stat().st_mtime_ns for p in (out / "scores").glob("*.json")}
    assert len(scored) == 4
    assert hashlib.sha256(stage.read_bytes()).hexdigest() == before  # the stage is only read
    # Rerun: nothing is rendered or scored again; --apply-layer writes the winner over the stage.
    layer = tmp_path / "applied.usda"
    code, stdout, err = run_cli(capsys, "rig-study", *args, "--apply", "best", "--apply-layer", layer)
    assert code == 0, err
    assert "scoring" not in err and {p.name: p.stat().st_mtime_ns for p in (out / "scores").glob("*.json")} == scored
    winner = stdout.split("best for disparity: ")[1].split(";")[0]
    spec = rigs(open_stage(layer))["best"].spec
    assert f"b{spec.baseline:g}".replace(".", "p") == winner.split("_")[0] and (spec.rows, spec.cols) == (3, 3)
    assert (spec.width, spec.height) == (PLANE_RIG.width, PLANE_RIG.height)
    assert hashlib.sha256(stage.read_bytes()).hexdigest() == before
    # Other settings in the same folder are refused in one line.
    other = [("3" if a == "2" else a) for a in args]  # --samples 3
    code, _, err = run_cli(capsys, "rig-study", *other)
    assert_one_line_error(code, err, "other settings", "samples")


def test_rig_study_bad_input(capsys, tmp_path):
    code, _, err = run_cli(capsys, "rig-study", tmp_path / "missing.usda", "-o", tmp_path / "s")
    assert_one_line_error(code, err, "does not exist")
    code, _, err = run_cli(capsys, "rig-study", STAGES / "static_boxes.usda", "-o", tmp_path / "s", "--spacing", "uniform,wavy")
    assert_one_line_error(code, err, "wavy", "--spacing")
    assert not (tmp_path / "s").exists()


@pytest.mark.parametrize("entry", ["report.md", "scores", "heatmaps", "scores/.c_b0p05_uniform.json.tmp", "score_vs_baseline.png"])
def test_a_study_folder_with_a_link_where_lfusd_writes_is_refused_and_the_target_untouched(tmp_path, entry):
    """Issue 39 item 1: a study folder follows the dataset folder's rule, no link followed."""
    from lfusd.errors import LfusdError
    from lfusd.study.run import STUDY_FORMAT, _prepare_folder

    home = tmp_path / "home"
    home.mkdir()
    (home / "thesis.tex").write_text("the user's")
    out = tmp_path / "study"
    (out / "scores").mkdir(parents=True)
    record = {"format": STUDY_FORMAT, "version": 1, "stage": "s.usda", "stage_id": "abc", "settings": {"grid": [3, 3]}}
    (out / "study.json").write_text(json.dumps(record))
    link = out / entry
    if link.exists():
        link.rmdir()
    link.symlink_to(home if "." not in entry else home / "thesis.tex")
    with pytest.raises(LfusdError, match="symbolic link") as e:
        _prepare_folder(out, record)
    assert str(link) in str(e.value) and "\n" not in str(e.value)
    assert [p.name for p in home.iterdir()] == ["thesis.tex"] and (home / "thesis.tex").read_text() == "the user's"


def test_the_study_report_and_figures_replace_a_file_whole_never_write_through_it(tmp_path):
    """Issue 39 item 1: report.md and the PNGs are written under a new temporary name and renamed
    (a file or link found at their name is replaced, its target untouched)."""
    from matplotlib.figure import Figure

    from lfusd.study.report import _save

    target = tmp_path / "thesis.tex"
    target.write_text("the user's")
    png = tmp_path / "overview.png"
    png.symlink_to(target)
    fig = Figure(figsize=(1, 1))
    fig.subplots().plot([0, 1])
    _save(fig, png)
    assert target.read_text() == "the user's" and not png.is_symlink() and png.read_bytes()[:4] == b"\x89PNG"

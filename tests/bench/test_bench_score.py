"""`lfusd bench oracle` and `lfusd bench score`: the oracle scores perfectly, a perturbed oracle
scores worse by what the perturbation implies (computed here from the ground truth), the scorer's
metrics are `lfusd eval`'s, bad submissions and a changed gt/ are one-line errors, and baseline (a)
runs from the public inputs alone."""

from __future__ import annotations

import json
import shutil

import numpy as np
import pytest

from support.cli import assert_one_line_error, run_cli

from lfusd.bench import score as bench_score
from lfusd.data.dataset import Dataset


def test_spread_is_the_rms_distance_to_the_mean_over_the_views_that_see_the_point():
    a, b, c = np.array([0.0, 0, 0]), np.array([0.2, 0, 0]), np.array([0.0, 0.3, 0.4])
    flows = np.stack([[a, a], [b, c], [c, c]])  # (V=3, N=2, 3)
    seen = np.array([[True, True], [True, False], [False, True]])
    s = bench_score.spread(flows, seen)
    assert s[0] == pytest.approx(0.1)  # two views, |a - b| / 2
    assert s[1] == pytest.approx(0.25)  # a and c: |a - c| / 2 = 0.5 / 2; view 1 (not seeing it) is left out


_RESULTS = shutil.ignore_patterns("score.json", "score.csv", "leaderboard.md")  # another test's scores of the oracle


def _scene(root):
    rec = json.loads((root / "bench.json").read_text())
    scene = rec["splits"]["test"][0]
    return scene, Dataset(root / "gt" / scene)


@pytest.fixture(scope="module")
def oracle(tiny_bench, tmp_path_factory):
    from lfusd.cli import main

    code, root = tiny_bench
    assert code == 0
    sub = tmp_path_factory.mktemp("sub") / "oracle"
    assert main(["bench", "oracle", str(root), "-o", str(sub)]) == 0
    return root, sub


@pytest.mark.render
def test_the_oracle_scores_perfectly_on_every_region(oracle, capsys):
    root, sub = oracle
    code, out, _ = run_cli(capsys, "bench", "score", sub, "--bench", root)
    assert code == 0 and "| oracle | 0 | 0 |" in out
    res = json.loads((sub / "score.json").read_text())
    rows = (sub / "score.csv").read_text().splitlines()
    assert rows[0].startswith("sequence,region,") and len(rows) == 1 + 2 * len(bench_score.REGIONS)
    assert (sub / "leaderboard.md").read_text().splitlines()[2].startswith("| oracle |")
    for scope in [res["overall"], *res["sequences"].values()]:
        for region in bench_score.REGIONS:
            r = scope[region]
            if not r["pixels_motion"]:
                continue
            for k in ("epe_px", "fl_all_pct", "mse_x100", "badpix_0.01_pct", "dchange_epe_px", "epe3d_m", "outlier3d_pct",
                      "d1_pct", "d2_pct", "fl_pct", "sf_pct"):
                assert r[k] == 0.0, (region, k)
            assert r["acc3d_strict_pct"] == 100.0 and r["acc3d_relax_pct"] == 100.0
        a = scope["angular"]
        assert a["angular_points"] > 0 and a["angular_spread_m"] == a["angular_spread_gt_m"] < 1e-4
    assert res["overall"]["all"]["pixels_motion"] > 500 and res["overall"]["moving"]["pixels_motion"] > 0


def _perturb(sub, scene, ds, out, views=None, **delta):
    """A copy of submission ``sub`` with ``delta`` added to the arrays of ``views`` (default all)."""
    shutil.copytree(sub, out, ignore=_RESULTS)
    for f in ds.frames[:-1]:
        for v in views or ds.views:
            p = bench_score.submission_path(out, scene, f, v)
            with np.load(p) as z:
                a = {k: z[k] for k in z.files}
            for k, d in delta.items():
                a[k] = (a[k] + np.float32(d)).astype(np.float32) if np.ndim(d) == 0 else (a[k] + np.asarray(d, np.float32)).astype(np.float32)
            bench_score._savez(p, a)
    return out


@pytest.mark.render
def test_a_perturbed_oracle_scores_worse_by_what_the_perturbation_implies(oracle, tmp_path):
    root, sub = oracle
    scene, ds = _scene(root)
    bad = _perturb(sub, scene, ds, tmp_path / "bad", flow=[3.0, 4.0], disparity=0.05, disparity_change=0.25, scene_flow=[0.0, 0.2, 0.0])
    res = bench_score.score_submission(bad, root)
    # By hand from the ground truth: the flow error is 5 px everywhere, the disparity error 0.05 px,
    # the change error 0.25 px (so disparity at t+1 is off by 0.3 px), the scene-flow error 0.2 m.
    g3, n_surface = [], 0
    for f in ds.frames[:-1]:
        for v in ds.views:
            valid = np.asarray(ds.read(f, v, "valid_fwd"), bool)
            sf = np.asarray(ds.read(f, v, "scene_flow"), np.float64)[valid]
            g3.append(np.linalg.norm(sf, axis=-1))
            n_surface += int(np.isfinite(ds.read(f, v, "depth")).sum())
    g3 = np.concatenate(g3)
    want = {"epe_px": 5.0, "fl_all_pct": 100.0, "epe_gt_1px_pct": 100.0,  # 5 > 3 px and > 5 % of every true flow here (< 100 px)
            "mse_x100": 100 * 0.05**2, "badpix_0.01_pct": 100.0, "badpix_0.03_pct": 100.0, "badpix_0.07_pct": 0.0,
            "dchange_epe_px": 0.25, "d1_pct": 0.0, "d2_pct": 0.0, "fl_pct": 100.0, "sf_pct": 100.0, "epe3d_m": 0.2,
            # 0.2 m: never < 0.05 or < 0.1 m, never > 0.3 m; relative to |gt| + 1e-4 it is < 5 % / < 10 % / > 10 % by |gt|
            "acc3d_strict_pct": 100 * np.mean(0.2 / (g3 + 1e-4) < 0.05), "acc3d_relax_pct": 100 * np.mean(0.2 / (g3 + 1e-4) < 0.1),
            "outlier3d_pct": 100 * np.mean(0.2 / (g3 + 1e-4) > 0.1)}
    got = res["overall"]["all"]
    assert got["pixels_motion"] == g3.size and got["pixels_disparity"] == n_surface
    for k, w in want.items():
        assert got[k] == pytest.approx(w, rel=1e-4, abs=1e-6), k
    assert want["outlier3d_pct"] > 50  # most points move less than 2 m: the test compares something
    # A bias shared by every view leaves the angular spread at the ground truth's floor; one view off raises it.
    a = res["overall"]["angular"]
    assert a["angular_spread_m"] == pytest.approx(a["angular_spread_gt_m"], abs=1e-6)
    one = ds.views[-1]
    skew = bench_score.score_submission(_perturb(sub, scene, ds, tmp_path / "skew", views=[one], scene_flow=[0.0, 0.2, 0.0]), root)
    assert skew["overall"]["angular"]["angular_spread_m"] > a["angular_spread_gt_m"] + 0.01


@pytest.mark.render
def test_the_scorer_equals_lfusd_eval_where_they_overlap(oracle, tmp_path):
    """Noise on every array; each view's bench metrics (region 'all') equal `lfusd eval --protocol lfusd`'s row, and the
    overall figures are eval's rows pooled by their pixels."""
    from lfusd.evaluation import score as eval_score

    root, sub = oracle
    scene, ds = _scene(root)
    rng = np.random.default_rng(3)
    noisy = tmp_path / "noisy"
    shutil.copytree(sub, noisy, ignore=_RESULTS)
    preds = {}
    for f in ds.frames[:-1]:
        for v in ds.views:
            p = bench_score.submission_path(noisy, scene, f, v)
            with np.load(p) as z:
                a = {k: (z[k] + rng.normal(0, s, z[k].shape)).astype(np.float32) for k, s in
                     (("flow", 4.0), ("disparity", 0.1), ("disparity_change", 2.0), ("scene_flow", 0.2))}
            bench_score._savez(p, a)
            preds[(f, v)] = a
    evald = {t: tmp_path / t for t in ("disparity", "flow", "sceneflow")}
    for d in evald.values():
        d.mkdir()
    for (f, v), a in preds.items():
        stem = f"{f:04d}_{v[0]:02d}_{v[1]:02d}"
        np.save(evald["disparity"] / f"{stem}.npy", a["disparity"])
        np.save(evald["flow"] / f"{stem}.npy", a["flow"])
        np.save(evald["sceneflow"] / f"{stem}.npy", a["scene_flow"])
        np.save(evald["sceneflow"] / f"{stem}_disp.npy", a["disparity"])
        np.save(evald["sceneflow"] / f"{stem}_disp2.npy", a["disparity"] + a["disparity_change"])
        np.save(evald["sceneflow"] / f"{stem}_flow.npy", a["flow"])
    rows = {t: eval_score.evaluate(root / "gt" / scene, d, t) for t, d in evald.items()}
    res = bench_score.score_submission(noisy, root)["overall"]["all"]
    pooled_checked = 0
    for task, keys in (("disparity", ("mse_x100", "badpix_0.01_pct", "badpix_0.03_pct", "badpix_0.07_pct")),
                       ("flow", ("epe_px", "fl_all_pct", "epe_gt_1px_pct")),
                       ("sceneflow", ("epe3d_m", "acc3d_strict_pct", "acc3d_relax_pct", "outlier3d_pct", "d1_pct", "d2_pct", "fl_pct", "sf_pct"))):
        for row in rows[task]:
            view = (row["row"], row["col"])
            mine = bench_score.view_tally(preds[(row["frame"], view)], bench_score._truth(ds, row["frame"], view))["all"]
            for k in keys:
                s, n = mine[k]
                assert n == row["pixels"] and s / n == pytest.approx(row[k], rel=1e-12, abs=1e-12), (task, k, view)
        for k in keys:
            pooled = sum(r[k] * r["pixels"] for r in rows[task]) / sum(r["pixels"] for r in rows[task])
            assert res[k] == pytest.approx(pooled, rel=1e-12), k
            pooled_checked += 1
    assert pooled_checked == 15 and 0 < res["epe_px"] and 0 < res["d2_pct"] < 100


@pytest.mark.render
@pytest.mark.parametrize("damage", ["missing", "shape", "nan", "not_npz", "no_array"])
def test_a_bad_submission_is_one_line_naming_the_file(oracle, tmp_path, capsys, damage):
    root, sub = oracle
    scene, ds = _scene(root)
    bad = tmp_path / "bad"
    shutil.copytree(sub, bad, ignore=_RESULTS)
    p = bench_score.submission_path(bad, scene, ds.frames[0], ds.views[1])
    with np.load(p) as z:
        a = {k: z[k] for k in z.files}
    if damage == "missing":
        p.unlink()
    elif damage == "shape":
        a["flow"] = a["flow"][:-1]
    elif damage == "nan":
        a["scene_flow"][3, 4, 1] = np.nan
    elif damage == "no_array":
        del a["disparity_change"]
    if damage == "not_npz":
        p.write_bytes(b"\x89PNG\r\n\x1a\n not an archive")
    elif damage != "missing":
        bench_score._savez(p, a)
    code, _, err = run_cli(capsys, "bench", "score", bad, "--bench", root)
    assert code == 2
    assert_one_line_error(code, err, str(p), {"missing": "missing", "shape": "shape", "nan": "NaN", "not_npz": "not an .npz",
                                              "no_array": "disparity_change"}[damage])
    assert not (bad / "score.json").exists()


@pytest.mark.render
def test_score_refuses_a_changed_test_ground_truth(oracle, tmp_path, capsys):
    root, sub = oracle
    copy = tmp_path / "bench"
    shutil.copytree(root, copy, ignore=shutil.ignore_patterns("render", "public"))
    scene, _ = _scene(copy)
    target = sorted((copy / "gt" / scene).rglob("motion.exr"))[0]
    data = bytearray(target.read_bytes())
    data[-10] ^= 0xFF
    target.write_bytes(bytes(data))
    code, _, err = run_cli(capsys, "bench", "score", sub, "--bench", copy)
    assert_one_line_error(code, err, str(target), "changed")


@pytest.mark.render
def test_baseline_a_writes_a_submission_from_the_public_inputs_alone(oracle, tmp_path, capsys):
    root, _ = oracle
    public_only = tmp_path / "public_only"
    public_only.mkdir()
    shutil.copy(root / "bench.json", public_only / "bench.json")
    shutil.copytree(root / "public", public_only / "public")
    code, out, _ = run_cli(capsys, "bench", "baseline", public_only, "-o", tmp_path / "dis", "--planes", "16")
    assert code == 0, out
    code, out, _ = run_cli(capsys, "bench", "score", tmp_path / "dis", "--bench", root, "--method", "DIS + plane sweep")
    assert code == 0 and "| DIS + plane sweep |" in out
    res = json.loads((tmp_path / "dis" / "score.json").read_text())["overall"]["all"]
    assert res["epe_px"] > 0 and res["epe3d_m"] > 0  # an estimate, not the ground truth


class _PlaneRig:
    """A 1x2 rig (views (0,0) and (0,1), 0.5 m apart along x, OpenCV axes = world axes) before a
    fronto-parallel plane at z = 5 m: disparity f b / z = 2 px exactly, so view (0,1) sees the centre's
    pixel (u, v) at (u - 2, v)."""

    W, H, F, B, Z = 16, 12, 20.0, 0.5, 5.0

    class rig:
        centre_view = (0, 0)

    def intrinsics(self, view):
        return np.array([[self.F, 0, (self.W - 1) / 2], [0, self.F, (self.H - 1) / 2], [0, 0, 1.0]])

    def cam_to_world(self, frame, view):
        m = np.eye(4)
        m[0, 3] = self.B * view[1]
        return m

    def truth(self, view, flow):
        K = self.intrinsics(view)
        v, u = np.mgrid[0:self.H, 0:self.W].astype(np.float64)
        pos = np.stack([(u - K[0, 2]) * self.Z / self.F + self.B * view[1], (v - K[1, 2]) * self.Z / self.F, np.full(u.shape, self.Z)], -1)
        return {"valid_fwd": np.ones(u.shape, bool), "position": pos, "depth": np.full(u.shape, self.Z),
                "scene_flow": np.broadcast_to(np.asarray(flow, np.float64), pos.shape).copy()}


def test_correspondences_follow_the_light_field_geometry_and_skip_another_surface():
    ds = _PlaneRig()
    truths = {(0, 0): ds.truth((0, 0), [0, 0, 0]), (0, 1): ds.truth((0, 1), [0, 0, 0])}
    truths[(0, 1)]["position"][:, 5] += [0, 0, 1.0]  # column 5 of view (0,1) sees a surface 1 m behind
    X, corr = bench_score.correspondences(ds, 1, truths)
    v, u = np.mgrid[0:ds.H, 0:ds.W]
    assert len(X) == ds.H * ds.W
    seen0, idx0 = corr[(0, 0)]
    assert seen0.all() and np.array_equal(idx0, (v * ds.W + u).ravel())
    seen1, idx1 = corr[(0, 1)]
    want = ((u >= 2) & (u - 2 != 5)).ravel()  # inside the image, and not the other surface
    assert np.array_equal(seen1, want)
    assert np.array_equal(idx1[want], (v * ds.W + u - 2).ravel()[want])


def test_angular_spread_of_two_views_that_disagree_by_delta_is_half_of_it():
    ds = _PlaneRig()
    c, delta = np.array([0.1, 0.0, -0.2]), np.array([0.0, 0.06, 0.08])  # |delta| = 0.1 m
    truths = {(0, 0): ds.truth((0, 0), c), (0, 1): ds.truth((0, 1), c)}
    preds = {(0, 0): {"scene_flow": truths[(0, 0)]["scene_flow"]}, (0, 1): {"scene_flow": truths[(0, 1)]["scene_flow"] + delta}}
    sp, sg, n = bench_score.angular(ds, 1, truths, preds)
    assert n == ds.H * (ds.W - 2)  # the points both views see
    assert sp / n == pytest.approx(0.05) and sg == 0.0

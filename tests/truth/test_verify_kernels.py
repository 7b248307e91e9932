"""lfusd.truth.verify's compiled passes against their rules written out pixel by pixel: the per-key
errors, the over-limit test, the two-limit mixed decision, the label rows with their radix-selected percentiles and the corner trace of the mixed rule."""

import math

import numpy as np
import pytest

from lfusd.keys import BACKGROUND_DEPTH
from lfusd.truth import verify as V

INF = math.inf
NAN = math.nan


def _pixels():
    """Flat dataset arrays and traces (t, towards t+1) over hand-picked pixels: each row one case."""
    # (d_ds, mesh, d_tr, inst_ds, sem_ds, n_ds, valid_ds, valid_tr, flow_ds, flow_tr, sf_ds, sf_tr, dc_ds, dc_tr, occ_ds, occ_tr, hit)
    up = (0.0, 0.0, 1.0)
    rows = [
        (2.0, 0, 2.0002, 1, 5, up, True, True, (1.0, 0.0), (1.03, 0.04), (0.0, 0, 0), (0.001, 0, 0), 0.5, 0.52, False, False, 1.0),
        (INF, 0, 3.0, 1, 5, up, True, True, (0, 0), (0, 0), (0, 0, 0), (0, 0, 0), 0, 0, False, False, 1.0),  # only the trace sees it
        (BACKGROUND_DEPTH, -1, INF, 0, 0, up, False, False, (0, 0), (NAN, NAN), (0, 0, 0), (NAN,) * 3, 0, NAN, False, False, NAN),
        (4.0, -1, INF, 1, 5, up, True, False, (0, 0), (NAN, NAN), (0, 0, 0), (NAN,) * 3, 0, NAN, False, False, NAN),  # only the dataset
        (2.0, 1, 2.0, 1, 7, (0.0, 0.0, -1.0), True, True, (0, 0), (0, 0), (0, 0, 0), (0.0, 0.0, 0.0004), 0, 0, True, False, 0.99995),
        (2.0, 1, 2.0, 2, 7, (0.0, 0.0, 1.1), False, True, (9, 9), (0, 0), (0, 0, 0), (0, 0, 0), 0, 0, True, False, 0.5),
        (2.0, 0, 2.0, 1, 5, (0.6, 0.0, 0.8), True, True, (0, 0), (0, 0), (0, 0, 0), (0, 0, 0), 0, 0, True, False, 0.5),
    ]
    cols = list(zip(*rows))
    ds = {"depth": np.array(cols[0], np.float32), "instance": np.array(cols[3], np.int32), "semantic": np.array(cols[4], np.int32),
          "normal": np.array(cols[5], np.float32), "valid_fwd": np.array(cols[6]), "flow_fwd": np.array(cols[8], np.float32),
          "scene_flow": np.array(cols[10], np.float32), "disparity_change": np.array(cols[12], np.float32),
          "occlusion_fwd": np.array(cols[14])}
    normal_tr = np.tile(up, (len(rows), 1))
    st = {"mesh": np.array(cols[1], np.int64), "depth": np.array(cols[2]), "normal": normal_tr}
    # mesh 0: object 1 (1 m across), mesh 1: object 2 (2 mm across: scene flow held to 2 micrometres)
    bounds = np.array([[[0, 0, 0], [1, 0, 0]], [[0, 0, 0], [0.002, 0, 0]]], float)
    fw = {"mesh": st["mesh"], "valid": np.array(cols[7]), "flow": np.array(cols[9], float), "scene_flow": np.array(cols[11], float),
          "disparity_change": np.array(cols[13], float), "occluded": np.array(cols[15]), "visibility_hit": np.array(cols[16], float),
          "mesh_bounds": bounds}
    ids = np.array([1, 2, 0])  # per mesh, background last
    classes = np.array([0, 5, 7])
    return ds, st, fw, ids, classes


def _by_hand(ds, st, fw, ids, classes, thr):
    """Every key's error at every pixel from the rules of verify's module docstring, one pixel at a time."""
    out = {k: [] for k in ("depth", "instance", "semantic", "normal", "valid_fwd", "flow_fwd", "scene_flow", "disparity_change",
                           "occlusion_fwd")}
    sizes = [1.0, 0.002]
    for i in range(len(ds["depth"])):
        d = float(ds["depth"][i])
        m = int(st["mesh"][i])
        fg_ds, fg_tr = math.isfinite(d) and d < BACKGROUND_DEPTH, m >= 0
        both = fg_ds and fg_tr
        inst_tr = int(ids[m])
        out["depth"].append(abs(d - st["depth"][i]) / st["depth"][i] if both else NAN)
        out["instance"].append(float(int(ds["instance"][i]) != inst_tr or fg_ds != fg_tr) if fg_ds or fg_tr else NAN)
        out["semantic"].append(float(int(ds["semantic"][i]) != classes[inst_tr]) if both else NAN)
        n = [float(x) for x in ds["normal"][i]]
        length = math.sqrt(sum(x * x for x in n))
        cos = sum(a * b for a, b in zip(n, st["normal"][i])) / length
        out["normal"].append((1 - cos if abs(length - 1) <= V.NORMAL_LENGTH_TOL else 2.0) if both else NAN)
        out["valid_fwd"].append(float(bool(ds["valid_fwd"][i]) != bool(fw["valid"][i])) if both else NAN)
        ok = both and fw["valid"][i] and ds["valid_fwd"][i]
        f = [float(x) for x in ds["flow_fwd"][i]]
        out["flow_fwd"].append(math.dist(f, fw["flow"][i]) if ok else NAN)
        limit = max(min(thr["scene_flow"], V.SCENE_FLOW_REL * sizes[max(m, 0)]), V.SCENE_FLOW_FLOOR)
        sf = [float(x) for x in ds["scene_flow"][i]]
        out["scene_flow"].append(math.dist(sf, fw["scene_flow"][i]) * thr["scene_flow"] / limit if ok else NAN)
        out["disparity_change"].append(abs(float(ds["disparity_change"][i]) - fw["disparity_change"][i]) if ok else NAN)
        h = fw["visibility_hit"][i]
        tie = 1 - 10 * V.VISIBLE_EPS <= h <= 1 - V.VISIBLE_EPS / 10
        out["occlusion_fwd"].append(float(not (bool(ds["occlusion_fwd"][i]) == bool(fw["occluded"][i]) or tie)) if ok else NAN)
    return {k: np.array(v) for k, v in out.items()}


@pytest.mark.parametrize("stored", [np.float32, np.float64])
def test_every_keys_errors_follow_their_rule_pixel_by_pixel(stored):
    """One compiled pass per direction gives each key's error by its rule at every pixel (NaN where
    not compared): depth where both see a surface, instance where either does, the small object's
    scene flow scaled to its size, the occlusion tie band; the same at a subset of pixels, and with
    the dataset's floats stored as float32 or float64."""
    ds, st, fw, ids, classes = _pixels()
    ds = {k: (a.astype(stored) if a.dtype.kind == "f" else a) for k, a in ds.items()}
    thr = {**V.THRESHOLDS, **V.EXACT}
    want = _by_hand(ds, st, fw, ids, classes, thr)
    err = V._errors(ds, slice(None), st, fw, None, ids, thr, classes)
    assert list(err) == list(want)
    for k in want:
        np.testing.assert_allclose(err[k], want[k], rtol=1e-12, atol=1e-15, err_msg=k)
    # the errors this table was built to show
    assert err["instance"][[1, 3, 5]].tolist() == [1, 1, 0] and np.isnan(err["instance"][2]) and err["valid_fwd"][5] == 1
    assert err["normal"][[4, 5]].tolist() == [2.0, 2.0] and err["normal"][6] == pytest.approx(0.2)
    assert err["scene_flow"][4] == pytest.approx(4e-4 * 1e-3 / V.SCENE_FLOW_FLOOR, rel=1e-6)  # 2 mm: its storage step
    assert err["occlusion_fwd"][4] == 0 and np.isnan(err["occlusion_fwd"][5]) and err["occlusion_fwd"][6] == 1
    over = V._over(err, thr)
    by_hand = np.zeros(len(over), bool)
    for k, e in want.items():
        with np.errstate(invalid="ignore"):
            by_hand |= e > (0.5 if V.UNITS[k] == "frac" else thr[k])
    assert over.tolist() == by_hand.tolist() and over[0] and not over[2]
    idx = np.array([6, 0, 4])
    sub = V._errors(ds, idx, {k: a[idx] for k, a in st.items()}, {k: (a[idx] if k != "mesh_bounds" else a) for k, a in fw.items()},
                    None, ids, thr, classes)
    for k in want:
        np.testing.assert_allclose(sub[k], want[k][idx], rtol=1e-12, atol=1e-15, err_msg=k)


def test_a_traced_disparity_change_that_is_not_finite_is_not_compared():
    """Where the traced disparity change is not finite at a compared pixel (no baseline), the key is
    left out, as before the pass was compiled; the other keys keep their rows."""
    ds, st, fw, ids, classes = _pixels()
    fw["disparity_change"] = np.full(len(ds["depth"]), NAN)
    err = V._errors(ds, slice(None), st, fw, None, ids, {**V.THRESHOLDS, **V.EXACT}, classes)
    assert "disparity_change" not in err and "occlusion_fwd" in err
    assert V._over(err, {**V.THRESHOLDS, **V.EXACT})[0]  # the rows left still decide


def test_the_two_limit_mixed_decision_is_two_single_decisions():
    """The corner rule decided under two sets of limits in one pass equals deciding each alone."""
    rng = np.random.default_rng(3)
    H, W = 9, 11
    n = (H + 1) * (W + 1)
    ident = np.where(rng.random(n) < 0.03, rng.integers(-1, 3, n), 1)  # mostly one object
    depth = np.where(ident >= 0, 2 + rng.normal(0, 0.004, n), np.inf)
    flow = rng.normal(0, 0.06, (n, 2))
    flow[rng.random(n) < 0.1] = np.nan
    for f in (None, flow):
        a, b = V._mixed_decision(ident, depth, f, H, W, 0.01, 0.5, 0.005, 0.25)
        assert a.tolist() == V._mixed_decision(ident, depth, f, H, W, 0.01, 0.5).tolist()
        assert b.tolist() == V._mixed_decision(ident, depth, f, H, W, 0.005, 0.25).tolist()
        assert 0 < a.sum() < b.sum() < H * W


@pytest.mark.parametrize("n", [1, 2, 3, 5, 100, 1001, 40_000, 200_003])
def test_label_rows_follow_their_rules(n):
    """One pass gives every label's row and the row of all labels together, as written out here: pixels
    compared (not NaN), over the limit, the first pixel of the greatest error, the sum, the tie kinds,
    and median and p99 exactly numpy's linear percentiles (radix-selected): spread and heavy-tailed
    errors, many equal ones, mostly exact zeros, signed zeros, infinities, negatives, values beyond
    the resolved buckets either way; a label without pixels; rates (over 0.5) without percentiles."""
    from lfusd.truth import _verify_numba as K

    rng = np.random.default_rng(n)
    cases = [rng.random(n), rng.lognormal(-12, 4, n), np.zeros(n), np.round(rng.normal(0, 1e-3, n), 5), -rng.random(n)]
    z = np.zeros(n)
    z[::3] = 1e-7
    z[1::7] = -0.0
    z[2::11] = np.inf
    cases.append(z)
    # mostly exact agreement (+0.0, never gathered), and beyond the resolved buckets either way
    cases.append(np.where(rng.random(n) < 0.7, 0.0, rng.lognormal(-12, 4, n)))
    cases.append(rng.choice([1e-300, 3e-300, 1e30, 2e30, 0.0, -0.0, 5e-20, 1.0, -1e-16], n))
    n_labels, n_kinds, limit = 4, 6, 1e-4
    q = np.array([50.0, 99.0])
    for x in cases:
        e = x.copy()
        e[rng.random(n) < 0.2] = np.nan  # not compared
        kind = rng.integers(0, n_kinds, n)
        # labels pixel by pixel, and in runs as along image rows (label 3 has no pixel either way)
        for code, rate in [(c, r) for c in (rng.integers(0, n_labels - 1, n), np.repeat(rng.integers(0, n_labels - 1, n // 7 + 1), 7)[:n])
                           for r in (False, True)]:
            count, over, worst, top, total, kinds, pct = K.label_stats(e, code, kind, n_labels, n_kinds, limit, rate, q)
            for r in range(n_labels + 1):
                idx = np.flatnonzero(((code == r) if r < n_labels else np.ones(n, bool)) & ~np.isnan(e))
                vals = e[idx]
                assert count[r] == len(vals)
                assert over[r] == int((vals > (0.5 if rate else limit)).sum())
                assert kinds[r].tolist() == np.bincount(kind[idx], minlength=n_kinds).tolist()
                if len(vals) == 0:
                    assert np.isnan(pct[r]).all()
                    continue
                assert worst[r] == idx[np.argmax(vals)] and top[r] == vals.max()
                with np.errstate(invalid="ignore"):
                    np.testing.assert_allclose(total[r], vals.sum(), rtol=1e-9)
                    want = np.full(2, np.nan) if rate else np.percentile(vals, [50, 99])
                assert np.array_equal(pct[r], want, equal_nan=True), (r, x[:5], pct[r], want)


def test_open3ds_cast_answer_resolves_to_mesh_and_triangle():
    """Per ray: the mesh of its geometry id (the scene's lookup table) where it hit something and
    the id is known, else -1; the triangle id as Open3D gives it."""
    from lfusd.truth import _verify_numba as K

    none = np.iinfo(np.uint32).max  # Open3D's invalid id
    t = np.array([1.0, INF, 2.0, 3.0, 0.5], np.float32)
    gid = np.array([0, none, 1, 7, 2], np.uint32)
    prim = np.array([5, none, 9, 2, 0], np.uint32)
    lut = np.array([2, 0, -1], np.int64)  # geometry 0: mesh 2, geometry 1: mesh 0, geometry 2: none (the table's last entry)
    mesh, tri = np.empty(5, np.int64), np.empty(5, np.int64)
    K.resolve_hits(t, gid, prim, lut, mesh, tri)
    assert mesh.tolist() == [2, -1, 0, -1, -1]
    assert tri.tolist() == [5, int(none), 9, 2, 0]

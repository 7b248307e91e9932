"""The compiled baselines (lfusd.evaluation._baselines_numba) against the implementations they replaced,
copied here as references: the PyTorch plane sweep (grid_sample warps, float32) and the NumPy / SciPy
ray flow (map_coordinates, sparse matrices, scipy's conjugate gradients). Same candidates, cost,
aggregation, refinement and iterations: the results agree to float rounding."""

from __future__ import annotations

import numpy as np
import pytest
import torch
import torch.nn.functional as F

from support.fake import FakeDataset
from lfusd.evaluation import _baselines_numba as nb
from lfusd.evaluation import baselines, rayflow
from lfusd.evaluation.rayflow import _box, _gradients, _grey_stack, _pyr_down, _spline


# ---- the plane sweep ------------------------------------------------------------------------------


def _sweep_reference(images, offsets, ref_offset, d_range, n_planes, window):
    """lfusd.evaluation.baselines.plane_sweep before the compiled kernel (PyTorch, CPU): (disparity,
    cost at the chosen plane, the cost volume (P,H,W), the chosen plane per pixel)."""
    keys = list(images)
    imgs = torch.stack([torch.from_numpy(np.array(images[k])).float().div(255).permute(2, 0, 1) for k in keys])
    v, c, h, w = imgs.shape
    rel = torch.tensor([[offsets[k][0] - ref_offset[0], offsets[k][1] - ref_offset[1]] for k in keys], dtype=torch.float32)
    ds = torch.linspace(float(d_range[0]), float(d_range[1]), n_planes)
    yy, xx = torch.meshgrid(torch.arange(h, dtype=torch.float32), torch.arange(w, dtype=torch.float32), indexing="ij")
    costs = torch.empty(n_planes, h, w)
    for s in range(n_planes):
        u = xx[None] - ds[s] * rel[:, 0, None, None]
        vv = yy[None] - ds[s] * rel[:, 1, None, None]
        grid = torch.stack([2 * u / max(w - 1, 1) - 1, 2 * vv / max(h - 1, 1) - 1], -1)
        wv = F.grid_sample(imgs, grid, mode="bilinear", padding_mode="border", align_corners=True)
        var = wv.var(dim=0, unbiased=False).sum(dim=0)
        costs[s] = F.avg_pool2d(var[None, None], window, stride=1, padding=window // 2, count_include_pad=False)[0, 0]
    best = costs.argmin(dim=0)
    i0, i2 = (best - 1).clamp(min=0), (best + 1).clamp(max=n_planes - 1)
    c0, c1, c2 = (costs.gather(0, i[None])[0] for i in (i0, best, i2))
    denom = c0 - 2 * c1 + c2
    delta = torch.where((denom > 1e-12) & (best > 0) & (best < n_planes - 1), 0.5 * (c0 - c2) / denom.clamp(min=1e-12), torch.zeros_like(c1))
    disp = ds[best] + delta.clamp(-0.5, 0.5) * (d_range[1] - d_range[0]) / (n_planes - 1)
    return disp.numpy(), c1.numpy(), costs.numpy(), best.numpy()


@pytest.fixture(scope="module")
def two_depths():
    ds = FakeDataset(rows=5, cols=5, width=64, height=48, frames=(1,))
    return {v: ds.read(1, v, "rgb") for v in ds.views}, {v: ds.rig.offsets(v) for v in ds.views}


# every view from the centre; the row and column of a corner (the benchmark's baselines); the four
# corners from a virtual view between them (view synthesis, lfusd.evaluation.baselines.interpolate_views)
CASES = [("all", (2, 2)), ("cross", (0, 0)), ("cross", (1, 3)), ("corners", (0.5, 1.5))]


@pytest.mark.parametrize("views,ref", CASES)
def test_the_compiled_plane_sweep_chooses_the_planes_of_the_torch_sweep(two_depths, views, ref):
    imgs, offs = two_depths
    if views == "corners":
        imgs = {v: imgs[v] for v in ((0, 0), (0, 4), (4, 0), (4, 4))}
        ref_off = (ref[1] - 2.0, ref[0] - 2.0)  # the rig's offsets: (col - 2, row - 2)
    else:
        ref_off = offs[ref]
        if views == "cross":
            imgs = {v: imgs[v] for v in imgs if v[0] == ref[0] or v[1] == ref[1]}
    d_range, n_planes, window = (0.4, 2.6), 48, 9
    disp, cost = baselines.plane_sweep(imgs, offs, ref_off, d_range, n_planes, window, device="cpu")
    disp_ref, cost_ref, costs_ref, best_ref = _sweep_reference(imgs, offs, ref_off, d_range, n_planes, window)
    # the costs are the same numbers up to the reference's float32 rounding (a variance of up to 25
    # samples, a mean of 81 of them; the coordinates normalised for grid_sample and back, 1e-5 px):
    # measured at most 4e-5 relative, and 2e-10 absolute (1.6e-4 relative) at the smallest costs (1e-6)
    np.testing.assert_allclose(cost, cost_ref, rtol=1e-4, atol=1e-9)
    # the chosen plane: the same, except where the reference's own costs of the two planes tie
    # within that rounding (measured: no such pixel on these views)
    step = (d_range[1] - d_range[0]) / (n_planes - 1)
    best = np.clip(np.round((disp - d_range[0]) / step), 0, n_planes - 1).astype(int)  # |refinement| <= step / 2
    moved = np.abs(disp - disp_ref) > 1e-3
    differ = best != best_ref
    assert not np.any(moved & ~differ), np.abs(disp - disp_ref)[~differ].max()  # same plane: same refinement to 1e-3 px
    if differ.any():
        a = np.take_along_axis(costs_ref, best[None], 0)[0][differ]
        b = np.take_along_axis(costs_ref, best_ref[None], 0)[0][differ]
        assert np.all(np.abs(a - b) <= 1e-4 * np.maximum(a, b) + 1e-9), "a different plane where the costs do not tie"
    assert differ.mean() <= 0.002, differ.sum()
    # where the plane agrees, the disparity does, to the refinement's rounding (measured: 8e-6 px)
    assert np.abs(disp - disp_ref)[~differ].max() < 1e-4


def test_the_gpu_sweep_and_the_compiled_sweep_build_one_cost_volume(two_depths):
    """baselines._sweep_costs_torch (the path on a GPU, run here on the CPU) and the kernel."""
    imgs, offs = two_depths
    keys = [v for v in imgs if v[0] == 2 or v[1] == 1]
    rel = [[offs[k][0] - offs[(2, 1)][0], offs[k][1] - offs[(2, 1)][1]] for k in keys]
    ds = torch.linspace(0.4, 2.6, 20)
    t = baselines._sweep_costs_torch(torch.stack([baselines._img_tensor(imgs[k], "cpu") for k in keys]), torch.tensor(rel), ds, 7, 8)
    a = np.stack([imgs[k] for k in keys]).astype(np.float32) / np.float32(255)
    k = nb.sweep_costs(a, np.asarray(rel, np.float64), ds.numpy().astype(np.float64), 7)
    np.testing.assert_allclose(k, t.numpy(), rtol=1e-4, atol=1e-9)


# ---- ray flow ---------------------------------------------------------------------------------------


def _sample(img, u, v):
    h, w = img.shape[:2]
    inside = (u >= 0) & (u <= w - 1) & (v >= 0) & (v <= h - 1)
    uc, vc = np.clip(u, 0, w - 1), np.clip(v, 0, h - 1)
    u0 = np.minimum(np.floor(uc).astype(np.intp), max(w - 2, 0))
    v0 = np.minimum(np.floor(vc).astype(np.intp), max(h - 2, 0))
    a, b = (uc - u0)[..., None], (vc - v0)[..., None]
    u1, v1 = np.minimum(u0 + 1, w - 1), np.minimum(v0 + 1, h - 1)
    return (1 - b) * ((1 - a) * img[v0, u0] + a * img[v0, u1]) + b * ((1 - a) * img[v1, u0] + a * img[v1, u1]), inside


def _sample_cubic(coef, u, v):
    from scipy import ndimage

    h, w = coef.shape[:2]
    coords = np.stack([np.clip(v, 0, h - 1).ravel(), np.clip(u, 0, w - 1).ravel()])
    return np.stack([ndimage.map_coordinates(coef[..., c], coords, order=3, mode="mirror", prefilter=False).reshape(u.shape) for c in range(coef.shape[2])], -1)


def _smoothness(h, w, disparity, sigma):
    import scipy.sparse as sp

    idx = np.arange(h * w).reshape(h, w)
    rows, cols, wts = [], [], []
    for a, b, da, db in ((idx[:, :-1], idx[:, 1:], disparity[:, :-1], disparity[:, 1:]), (idx[:-1], idx[1:], disparity[:-1], disparity[1:])):
        rows.append(a.ravel())
        cols.append(b.ravel())
        wts.append(np.exp(-np.abs(da - db) / sigma).ravel())
    r, c, wt = np.concatenate(rows), np.concatenate(cols), np.concatenate(wts)
    W = sp.coo_matrix((np.concatenate([wt, wt]), (np.concatenate([r, c]), np.concatenate([c, r]))), shape=(h * w, h * w)).tocsr()
    return sp.diags(np.asarray(W.sum(axis=1)).ravel()) - W


def _level_step_reference(I0, G1, S1, d, rel, K, V, solver, window, lam, sigma_d, robust, iterations):
    """lfusd.evaluation.rayflow._level_step before the compiled kernels."""
    import scipy.sparse as sp
    import scipy.sparse.linalg as spla

    fx, fy, cx, cy = K
    h, w = d.shape
    v, u = np.mgrid[0:h, 0:w].astype(np.float64)
    Z = fx / np.maximum(d, 1e-3)
    X, Y = (u - cx) / fx * Z, (v - cy) / fy * Z
    ref = []
    for s in range(len(I0)):
        us, vs = u - d * rel[s][0], v - d * rel[s][1]
        ref.append((_sample_cubic(_spline(I0[s]), us, vs), (us >= 0) & (us <= w - 1) & (vs >= 0) & (vs <= h - 1)))
    lap = _smoothness(h, w, d, sigma_d) if solver == "global" else None
    for _ in range(iterations):
        A = np.zeros((h, w, 3, 3))
        b = np.zeros((h, w, 3))
        Zp = np.maximum(Z + V[..., 2], 1e-3 * Z)
        for s in range(len(I0)):
            us = fx * (X + V[..., 0] - rel[s][0]) / Zp + cx
            vs = fy * (Y + V[..., 1] - rel[s][1]) / Zp + cy
            L1 = _sample_cubic(S1[s], us, vs)
            g, inside = _sample(G1[s], us, vs)
            nc = L1.shape[-1]
            L0, inside0 = ref[s]
            Lt = L1 - L0
            LX, LY = fx / Zp[..., None] * g[..., :nc], fy / Zp[..., None] * g[..., nc:]
            LZ = -((us - cx) / fx)[..., None] * LX - ((vs - cy) / fy)[..., None] * LY
            J = np.stack([LX, LY, LZ], -1)
            wgt = (inside & inside0)[..., None] / (1.0 + (Lt / robust) ** 2)
            Jw = np.swapaxes(J * wgt[..., None], -1, -2)
            A += Jw @ J
            b += (Jw @ Lt[..., None])[..., 0]
        scale = max(float(np.mean(np.trace(A, axis1=-2, axis2=-1))) / 3.0, 1e-12)
        if window > 1:
            AV = np.einsum("hwij,hwj->hwi", A, V)
            A = _box(A.reshape(h, w, 9), window).reshape(h, w, 3, 3)
            b = np.einsum("hwij,hwj->hwi", A, V) - _box(AV - b, window)
        if solver == "local":
            delta = np.linalg.solve(A + 1e-6 * scale * np.eye(3), -b[..., None])[..., 0]
        else:
            n = h * w
            Ab = sp.bsr_matrix((A.reshape(n, 3, 3), np.arange(n), np.arange(n + 1)), shape=(3 * n, 3 * n)).tocsr()
            Lk = sp.kron(lap, sp.identity(3), format="csr")
            M = Ab + lam * scale * Lk + 1e-6 * scale * sp.identity(3 * n)
            rhs = -b.reshape(-1) - lam * scale * (Lk @ V.reshape(-1))
            blocks = np.linalg.inv(A.reshape(n, 3, 3) + ((lam * scale * lap.diagonal() + 1e-6 * scale)[:, None, None] * np.eye(3)))
            prec = spla.LinearOperator(M.shape, matvec=lambda x: (blocks @ x.reshape(n, 3, 1)).reshape(-1), dtype=np.float64)
            sol, _ = spla.cg(M, rhs, M=prec, rtol=1e-5, maxiter=200)
            delta = sol.reshape(h, w, 3)
        V = V + delta
        if float(np.max(np.abs(delta))) < 1e-4:
            break
    return V


def _ray_flow_reference(images0, images1, offsets, ref_view, K, d, solver, window=7, lam=1.0, iterations=5, robust=0.1, edge=0.3):
    """lfusd.evaluation.rayflow.ray_flow before the compiled kernels (its default parameters)."""
    import cv2

    views = list(images0)
    h, w = d.shape
    rel = [(offsets[s][0] - offsets[ref_view][0], offsets[s][1] - offsets[ref_view][1]) for s in views]
    levels = max(1, int(np.floor(np.log2(min(h, w) / 16))) + 1)
    pyr = [([_grey_stack(images0[s]) for s in views], [_grey_stack(images1[s]) for s in views], d, (K[0, 0], K[1, 1], K[0, 2], K[1, 2]))]
    for _ in range(levels - 1):
        a0, a1, dl, (fx, fy, cx, cy) = pyr[-1]
        pyr.append(([_pyr_down(a) for a in a0], [_pyr_down(a) for a in a1], _pyr_down(dl[..., None])[..., 0] * 0.5, (fx / 2, fy / 2, cx / 2, cy / 2)))
    V = np.zeros(pyr[-1][2].shape + (3,))
    for lvl in range(levels - 1, -1, -1):
        a0, a1, dl, Kl = pyr[lvl]
        if V.shape[:2] != dl.shape:
            V = np.dstack([cv2.resize(V[..., i], (dl.shape[1], dl.shape[0]), interpolation=cv2.INTER_LINEAR) for i in range(3)])
        G1 = [np.concatenate(_gradients(a), -1) for a in a1]
        S1 = [_spline(a) for a in a1]
        V = _level_step_reference(a0, G1, S1, dl, rel, Kl, V, solver, window, lam, edge * 0.5**lvl, robust, iterations)
    return V


def _lf(t):
    """A 3x3 rig of a textured plane at 2 m with a still plane behind and a moving half-plane in front
    of its right half (tests/evaluation/test_rayflow.py's depth edge), uint8 as rendered."""
    from test_rayflow import OFFSETS, _step_view

    return {s: np.round(255 * _step_view(o, t)[0]).astype(np.uint8) for s, o in OFFSETS.items()}, OFFSETS


@pytest.mark.parametrize("solver", ["global", "local"])
def test_the_compiled_ray_flow_is_the_numpy_ray_flow(solver):
    from test_rayflow import B, F, K, STEP_Z, Z0, _step_view

    (i0, offs), (i1, _) = _lf(0), _lf(1)
    front = _step_view(offs[(0, 1)], 0)[1]
    d = np.where(front, F * B / STEP_Z, F * B / Z0) + 0.05 * np.sin(np.arange(front.shape[1]) / 3.0)  # not quite right, as a swept one
    got = rayflow.ray_flow(i0, i1, offs, (0, 1), K, d, solver=solver)
    ref = _ray_flow_reference(i0, i1, offs, (0, 1), K, d, solver)
    # in baselines (0.1 m here): 1e-6 is 0.1 micrometre, against motions of 0.5 baselines; the two differ by the
    # order of their sums only (measured: 1e-11), which the iterations do not amplify past it
    np.testing.assert_allclose(got, ref, rtol=0, atol=1e-6)
    # the work shared between reference views gives the same answer
    pair = rayflow.LightFieldPair(i0, i1)
    np.testing.assert_array_equal(rayflow.ray_flow(i0, i1, offs, (0, 1), K, d, solver=solver, pair=pair), got)


def test_a_pair_lends_its_second_frame_to_the_next_pair():
    (i0, _), (i1, _) = _lf(0), _lf(1)
    first = rayflow.LightFieldPair(i0, i1)
    nxt = rayflow.LightFieldPair(i1, i0, previous=first)
    fresh = rayflow.LightFieldPair(i1, i0)
    assert nxt.S0 is first.S1
    for a, b in zip(nxt.S0 + nxt.S1 + nxt.G1, fresh.S0 + fresh.S1 + fresh.G1):
        np.testing.assert_array_equal(a, b)


def test_cubic_samples_are_scipys():
    rng = np.random.default_rng(0)
    coef = rng.normal(size=(9, 13, 2))
    u = rng.uniform(-2, 15, (5, 7))  # beyond both borders too: clamped, as rayflow samples
    v = rng.uniform(-2, 11, (5, 7))
    u[0, :3] = [0.0, 12.0, 11.5]
    v[0, :3] = [8.0, 0.0, 8.0]
    np.testing.assert_allclose(nb.cubic_sample(coef, u, v), _sample_cubic(coef, u, v), rtol=0, atol=1e-12)


def test_the_block_preconditioned_cg_is_scipys():
    import scipy.sparse as sp
    import scipy.sparse.linalg as spla

    rng = np.random.default_rng(1)
    h, w = 6, 5
    n = h * w
    J = rng.normal(size=(n, 3, 2))
    A = J @ np.swapaxes(J, 1, 2)  # rank 2 per pixel, as one ray direction's equations: the smoothness completes it
    d = rng.uniform(1, 3, (h, w))
    lap = _smoothness(h, w, d, 0.3)
    wr, wd = rayflow._edge_weights(d, 0.3)
    lam, eps = 0.7, 1e-6
    rhs = rng.normal(size=3 * n)
    M = sp.bsr_matrix((A, np.arange(n), np.arange(n + 1)), shape=(3 * n, 3 * n)).tocsr() + lam * sp.kron(lap, sp.identity(3)) + eps * sp.identity(3 * n)
    np.testing.assert_allclose(nb.smooth_apply(rhs, wr, wd, lam), lam * sp.kron(lap, sp.identity(3)) @ rhs, atol=1e-12)
    blocks = np.linalg.inv(A + (lam * lap.diagonal() + eps)[:, None, None] * np.eye(3))
    prec = spla.LinearOperator(M.shape, matvec=lambda x: (blocks @ x.reshape(n, 3, 1)).reshape(-1), dtype=np.float64)
    for maxiter in (3, 200):  # stopped early and converged: the same iterates
        ref, _ = spla.cg(M, rhs, M=prec, rtol=1e-5, maxiter=maxiter)
        np.testing.assert_allclose(nb.block_cg(A, wr, wd, lam, eps, rhs, 1e-5, maxiter), ref, rtol=1e-8, atol=1e-10)


def test_the_3x3_solve_is_lapacks():
    rng = np.random.default_rng(2)
    A = rng.normal(size=(4, 5, 3, 3))
    A[0, 0] = [[0, 1, 2], [3, 4, 5], [6, 7, 9]]  # a zero first pivot: partial pivoting
    rhs = rng.normal(size=(4, 5, 3))
    eps = np.full((4, 5), 1e-3)
    np.testing.assert_allclose(nb.solve3(A, rhs, eps), np.linalg.solve(A + 1e-3 * np.eye(3), rhs[..., None])[..., 0], rtol=1e-9, atol=1e-12)


def test_the_sweeps_images_are_the_torch_paths_values():
    rng = np.random.default_rng(4)
    for img in (rng.integers(0, 256, (5, 6, 3), dtype=np.uint8), rng.integers(0, 256, (5, 6), dtype=np.uint8), rng.random((5, 6, 3))):
        np.testing.assert_array_equal(baselines._img_array(img), baselines._img_tensor(img, "cpu").permute(1, 2, 0).numpy())

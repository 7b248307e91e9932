"""Ray flow: 3-D scene flow from light-field gradients, after Ma, Smith & Gupta, "3D Scene Flow from
4D Light Field Gradients" (ECCV 2018). Our own NumPy/SciPy/OpenCV implementation of the method.

The ray flow equation. A point P = (X, Y, Z) in the reference view's camera frame (OpenCV axes,
units of the rig baseline b) is seen by the view at offset s (baselines, relative to the
reference) at u_s = f (X - s_x) / Z + c_x, v_s = f (Y - s_y) / Z + c_y: the light field
L(u, v, s_x, s_y). A displacement V = (V_X, V_Y, V_Z) of the point moves that ray by
du = (f/Z) (V_X - x_s V_Z), dv = (f/Z) (V_Y - y_s V_Z), x_s = (u_s - c_x) / f, and brightness
constancy along the ray gives, per ray,

    L_X V_X + L_Y V_Y + L_Z V_Z + L_t = 0,
    L_X = (f/Z) L_u = L_{s_x},  L_Y = (f/Z) L_v = L_{s_y},  L_Z = -(x_s L_X + y_s L_Y),

where L_{s_x} = d L_u (d = f b / Z the disparity) is the angular light-field gradient: depth enters
only through the light field's own structure. Ma et al. measure L_X, L_Y by finite differences
over a lenslet camera's sub-pixel view spacing; a rendered rig's views are pixels of disparity
apart, where a finite difference over one baseline step aliases, so here the angular gradient is
taken through the light-field correspondence, L_{s} = d grad L, with the disparity d of a plane
sweep (:func:`lfusd.evaluation.baselines.plane_sweep_disparity`).

One equation per ray (and colour channel) constrains three unknowns; as in the paper, V is found
from the rays of every view of one scene point (the correspondence structure of the light
field) together with one of two regularisers borrowed from optical flow:

- ``local`` (Lucas-Kanade ray flow): V is constant over a window; the 3x3 normal equations
  (the light-field structure tensor) are box-filtered and solved per pixel;
- ``global`` (Horn-Schunck ray flow): a data term plus a smoothness term lambda |grad V|^2 whose
  weights drop across disparity edges (structure-aware), solved as one sparse linear system. The
  data term is the local method's window-aggregated structure tensor (the paper's combined
  local-global method): per pixel, V_Z is weakly determined (x_s varies over the views by d / f
  only), and a per-pixel data term lets the smoothness carry one surface's V_Z across a depth edge
  into another (measured: 17 mm of a 50 mm dZ on a still plane beside a moving one, tests/evaluation/test_rayflow.py).

Both are iterated Gauss-Newton over a coarse-to-fine pyramid (the equation holds for differential
motion; warping the t+1 light field by the current estimate extends it to motions of pixels), with
a robust (Cauchy) weight per ray that discounts rays occluded in one view or frame.
"""

from __future__ import annotations

import logging

import numpy as np

from ..errors import LfusdError

log = logging.getLogger(__name__)

SOLVERS = ("local", "global")


def _grey_stack(img) -> np.ndarray:
    """(H,W,C) float64 in [0, 1] from uint8 or float RGB / grey."""
    a = np.asarray(img)
    f = a.astype(np.float64) / (255.0 if a.dtype == np.uint8 else 1.0)
    return f[..., None] if f.ndim == 2 else f


def _sample(img: np.ndarray, u: np.ndarray, v: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Bilinear samples of (H,W,C) at float pixel coordinates (pixel centres at integers, clamped at the
    border) and the inside mask. In float64: OpenCV's remap quantises the weights to 1/32 px, an error
    a gradient method reads as motion."""
    h, w = img.shape[:2]
    inside = (u >= 0) & (u <= w - 1) & (v >= 0) & (v <= h - 1)
    uc, vc = np.clip(u, 0, w - 1), np.clip(v, 0, h - 1)
    u0 = np.minimum(np.floor(uc).astype(np.intp), max(w - 2, 0))
    v0 = np.minimum(np.floor(vc).astype(np.intp), max(h - 2, 0))
    a, b = (uc - u0)[..., None], (vc - v0)[..., None]
    u1, v1 = np.minimum(u0 + 1, w - 1), np.minimum(v0 + 1, h - 1)
    out = (1 - b) * ((1 - a) * img[v0, u0] + a * img[v0, u1]) + b * ((1 - a) * img[v1, u0] + a * img[v1, u1])
    return out, inside


def _spline(img: np.ndarray) -> np.ndarray:
    """Cubic B-spline coefficients of (H,W,C), per channel (scipy.ndimage.spline_filter)."""
    from scipy import ndimage

    return np.stack([ndimage.spline_filter(img[..., c], order=3, mode="mirror") for c in range(img.shape[2])], -1)


def _sample_cubic(coef: np.ndarray, u: np.ndarray, v: np.ndarray) -> np.ndarray:
    """Cubic-spline samples of the image whose coefficients :func:`_spline` made: a bilinear
    resampling's error (several percent of a texture of 8 px wavelength) would read as motion."""
    from scipy import ndimage

    h, w = coef.shape[:2]
    coords = np.stack([np.clip(v, 0, h - 1).ravel(), np.clip(u, 0, w - 1).ravel()])
    return np.stack([ndimage.map_coordinates(coef[..., c], coords, order=3, mode="mirror", prefilter=False).reshape(u.shape) for c in range(coef.shape[2])], -1)


def _gradients(img: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Central-difference image gradients (H,W,C) along u and v."""
    gu = np.zeros_like(img)
    gv = np.zeros_like(img)
    gu[:, 1:-1] = 0.5 * (img[:, 2:] - img[:, :-2])
    gv[1:-1] = 0.5 * (img[2:] - img[:-2])
    return gu, gv


def _pyr_down(img: np.ndarray) -> np.ndarray:
    import cv2

    out = cv2.pyrDown(img.astype(np.float32))
    return (out[..., None] if out.ndim == 2 else out).astype(np.float64)


def _box(a: np.ndarray, window: int) -> np.ndarray:
    import cv2

    return cv2.blur(a.astype(np.float64), (window, window), borderType=cv2.BORDER_REFLECT)


def _solve3(A: np.ndarray, b: np.ndarray, eps: np.ndarray) -> np.ndarray:
    """Solve (A + eps I) x = b for stacks (...,3,3), (...,3)."""
    return np.linalg.solve(A + eps[..., None, None] * np.eye(3), b[..., None])[..., 0]


def _smoothness(h: int, w: int, disparity: np.ndarray, sigma: float):
    """Weighted graph Laplacian (N,N) of the 4-neighbour pixel grid, weights exp(-|d_p - d_q| / sigma)."""
    import scipy.sparse as sp

    idx = np.arange(h * w).reshape(h, w)
    rows, cols, wts = [], [], []
    for a, b, da, db in ((idx[:, :-1], idx[:, 1:], disparity[:, :-1], disparity[:, 1:]), (idx[:-1], idx[1:], disparity[:-1], disparity[1:])):
        wt = np.exp(-np.abs(da - db) / sigma).ravel()
        rows.append(a.ravel())
        cols.append(b.ravel())
        wts.append(wt)
    r, c, wt = np.concatenate(rows), np.concatenate(cols), np.concatenate(wts)
    W = sp.coo_matrix((np.concatenate([wt, wt]), (np.concatenate([r, c]), np.concatenate([c, r]))), shape=(h * w, h * w)).tocsr()
    return sp.diags(np.asarray(W.sum(axis=1)).ravel()) - W


def _level_step(I0, I1, G1, S1, d, rel, K, V, solver, window, lam, sigma_d, robust, iterations):
    """Gauss-Newton iterations of the ray flow at one pyramid level; returns V (H,W,3), baseline units."""
    import scipy.sparse as sp
    import scipy.sparse.linalg as spla

    fx, fy, cx, cy = K
    h, w = d.shape
    v, u = np.mgrid[0:h, 0:w].astype(np.float64)
    dd = np.maximum(d, 1e-3)  # a point at (numerically) infinite depth: its rays do not move; V is left to the regulariser
    Z = fx / dd
    X, Y = (u - cx) / fx * Z, (v - cy) / fy * Z
    # the rays of the reference pixel's point in every view at t: its light-field correspondence
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
            # where the moved point's ray lands in view s at t+1, and the ray flow coefficients there
            us = fx * (X + V[..., 0] - rel[s][0]) / Zp + cx
            vs = fy * (Y + V[..., 1] - rel[s][1]) / Zp + cy
            L1 = _sample_cubic(S1[s], us, vs)
            g, inside = _sample(G1[s], us, vs)  # (H,W,2C): d/du of every channel, then d/dv
            nc = L1.shape[-1]
            L0, inside0 = ref[s]
            Lt = L1 - L0  # (H,W,C)
            LX, LY = fx / Zp[..., None] * g[..., :nc], fy / Zp[..., None] * g[..., nc:]  # angular gradients d grad L (per channel)
            LZ = -((us - cx) / fx)[..., None] * LX - ((vs - cy) / fy)[..., None] * LY
            J = np.stack([LX, LY, LZ], -1)  # (H,W,C,3)
            wgt = (inside & inside0)[..., None] / (1.0 + (Lt / robust) ** 2)  # Cauchy weights: occluded rays disagree
            Jw = np.swapaxes(J * wgt[..., None], -1, -2)  # (H,W,3,C)
            A += Jw @ J
            b += (Jw @ Lt[..., None])[..., 0]
        scale = max(float(np.mean(np.trace(A, axis1=-2, axis2=-1))) / 3.0, 1e-12)
        if window > 1:
            # V constant over the window: each neighbour q's equations, linearised at its own V_q,
            # are moved to V_p: sum_q A_q V_p = sum_q (A_q V_q - b_q) (the box filter averages)
            AV = np.einsum("hwij,hwj->hwi", A, V)
            A = _box(A.reshape(h, w, 9), window).reshape(h, w, 3, 3)
            b = np.einsum("hwij,hwj->hwi", A, V) - _box(AV - b, window)  # the normal equations A (V + delta) = box(AV - b)
        if solver == "local":
            delta = _solve3(A, -b, np.full((h, w), 1e-6 * scale))
        else:
            n = h * w
            Ab = sp.bsr_matrix((A.reshape(n, 3, 3), np.arange(n), np.arange(n + 1)), shape=(3 * n, 3 * n)).tocsr()
            Lk = sp.kron(lap, sp.identity(3), format="csr")
            M = Ab + lam * scale * Lk + 1e-6 * scale * sp.identity(3 * n)
            rhs = -b.reshape(-1) - lam * scale * (Lk @ V.reshape(-1))
            # conjugate gradients (M is symmetric positive definite) with each pixel's 3x3 block
            # inverted as preconditioner: a direct factorisation costs seconds at 128x128
            blocks = np.linalg.inv(A.reshape(n, 3, 3) + ((lam * scale * lap.diagonal() + 1e-6 * scale)[:, None, None] * np.eye(3)))
            prec = spla.LinearOperator(M.shape, matvec=lambda x: (blocks @ x.reshape(n, 3, 1)).reshape(-1), dtype=np.float64)
            sol, _ = spla.cg(M, rhs, M=prec, rtol=1e-5, maxiter=200)  # Gauss-Newton refines the rest
            delta = sol.reshape(h, w, 3)
        V = V + delta
        if float(np.max(np.abs(delta))) < 1e-4:
            break
    return V


def ray_flow(images0: dict, images1: dict, offsets: dict, ref_view, K, disparity, solver: str = "global", window: int = 7,
             smoothness: float = 1.0, levels: int | None = None, iterations: int = 5, robust: float = 0.1, edge: float = 0.3, global_window: int = 7) -> np.ndarray:
    """3-D displacement of the point seen at every pixel of ``ref_view`` between t and t+1, in the
    reference camera's frame (OpenCV axes, units of the baseline), as if the rig stood still.

    ``images0`` / ``images1``: {view: (H,W,3) image} at t and t+1 (any views of a planar, parallel rig);
    ``offsets``: {view: (sx, sy)} in baselines; ``K``: the 3x3 intrinsics shared by the views;
    ``disparity``: (H,W) of the reference view at t, px per baseline step (d = f b / z).
    ``solver``: 'local' (window ``window``) or 'global' (data aggregated over ``global_window``;
    ``smoothness`` lambda, relative to the mean data term; ``edge``: px of disparity difference over
    which the smoothness weight falls by 1/e).
    ``robust``: the Cauchy scale of the temporal difference, in [0, 1] intensity. Returns (H,W,3) float64.
    """
    if solver not in SOLVERS:
        raise LfusdError(f"unknown ray flow solver {solver!r}; use one of {', '.join(SOLVERS)}")
    views = [v for v in images0 if v in images1]
    if not views or ref_view not in offsets:
        raise LfusdError("ray flow needs the views at t and t+1 and the reference view's offset")
    K = np.asarray(K, np.float64)
    d = np.asarray(disparity, np.float64)
    h, w = d.shape
    I0 = [_grey_stack(images0[s]) for s in views]
    I1 = [_grey_stack(images1[s]) for s in views]
    if any(a.shape[:2] != (h, w) for a in I0 + I1):
        raise LfusdError(f"ray flow needs every image at the disparity's size {w}x{h}")
    rel = [(offsets[s][0] - offsets[ref_view][0], offsets[s][1] - offsets[ref_view][1]) for s in views]
    if levels is None:
        levels = max(1, int(np.floor(np.log2(min(h, w) / 16))) + 1)
    pyr = [(I0, I1, d, (K[0, 0], K[1, 1], K[0, 2], K[1, 2]))]
    for _ in range(levels - 1):
        a0, a1, dl, (fx, fy, cx, cy) = pyr[-1]
        dl_small = _pyr_down(dl[..., None])[..., 0] * 0.5  # disparity is in pixels: it halves with the image
        # pyrDown's pixel x is the blurred source pixel 2x: x' = x / 2
        pyr.append(([_pyr_down(a) for a in a0], [_pyr_down(a) for a in a1], dl_small, (fx / 2, fy / 2, cx / 2, cy / 2)))
    V = np.zeros(pyr[-1][2].shape + (3,))
    for lvl in range(levels - 1, -1, -1):
        a0, a1, dl, Kl = pyr[lvl]
        if V.shape[:2] != dl.shape:
            import cv2

            # V is in baselines (no rescale) and smooth: resize's half-pixel grid, a quarter pixel
            # off pyrDown's, only shifts the next level's starting point, which it then refines
            V = np.dstack([cv2.resize(V[..., i], (dl.shape[1], dl.shape[0]), interpolation=cv2.INTER_LINEAR) for i in range(3)])
        G1 = [np.concatenate(_gradients(a), -1) for a in a1]
        S1 = [_spline(a) for a in a1]
        V = _level_step(a0, a1, G1, S1, dl, rel, Kl, V, solver, window if solver == "local" else global_window, smoothness, edge * 0.5**lvl, robust, iterations)
    return V


def compose(disparity, motion, K, baseline: float, cam_to_world0, cam_to_world1):
    """Submission arrays of one view from its disparity at t and the ray flow ``motion`` (camera
    frame, baselines): (flow (H,W,2) px, disparity_change (H,W) px, scene_flow (H,W,3) world metres).
    The world scene flow is C1 (P + V) - C0 P: the camera-frame motion plus the rig's own motion.
    Where the disparity is not positive or the moved point is behind the camera, zero motion."""
    d = np.asarray(disparity, np.float64)
    K = np.asarray(K, np.float64)
    fx, fy, cx, cy = K[0, 0], K[1, 1], K[0, 2], K[1, 2]
    h, w = d.shape
    v, u = np.mgrid[0:h, 0:w].astype(np.float64)
    ok = d > 1e-3
    with np.errstate(divide="ignore", invalid="ignore"):
        Z = np.where(ok, fx * baseline / d, 1.0)
    P = np.stack([(u - cx) / fx * Z, (v - cy) / fy * Z, Z], -1)
    P1 = P + np.asarray(motion, np.float64) * baseline
    ok &= P1[..., 2] > 1e-6 * Z
    z1 = np.where(ok, P1[..., 2], 1.0)
    flow = np.stack([fx * P1[..., 0] / z1 + cx - u, fy * P1[..., 1] / z1 + cy - v], -1)
    dchange = fx * baseline / z1 - d
    c0, c1 = np.asarray(cam_to_world0, np.float64), np.asarray(cam_to_world1, np.float64)
    sf = (P1 @ c1[:3, :3].T + c1[:3, 3]) - (P @ c0[:3, :3].T + c0[:3, 3])
    flow = np.where(ok[..., None], flow, 0.0)
    return flow, np.where(ok, dchange, 0.0), np.where(ok[..., None], sf, 0.0)

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


def _spline(img: np.ndarray) -> np.ndarray:
    """Cubic B-spline coefficients of (H,W,C), per channel (scipy.ndimage.spline_filter). Samples of
    them (_baselines_numba.cubic_sample) interpolate the image: a bilinear resampling's error
    (several percent of a texture of 8 px wavelength) would read as motion; so would OpenCV remap's
    weights, quantised to 1/32 px."""
    from scipy import ndimage

    return np.stack([ndimage.spline_filter(img[..., c], order=3, mode="mirror") for c in range(img.shape[2])], -1)


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


def _edge_weights(disparity: np.ndarray, sigma: float) -> tuple[np.ndarray, np.ndarray]:
    """Smoothness weights exp(-|d_p - d_q| / sigma) of the 4-neighbour pixel grid: (right (H,W-1), down (H-1,W))."""
    return np.exp(-np.abs(np.diff(disparity, axis=1)) / sigma), np.exp(-np.abs(np.diff(disparity, axis=0)) / sigma)


class LightFieldPair:
    """The parts of ray flow that depend on the images only, not on the reference view or its disparity:
    per pyramid level the grey stacks, their cubic-spline coefficients at t and t+1 and the image
    gradients at t+1 of every view. Build it once per frame pair and pass it to :func:`ray_flow` for
    every reference view (a 5x5 rig: 25 times less of this work); ``previous``, the pair of (t-1, t),
    lends its t+1 half as this pair's t."""

    def __init__(self, images0: dict, images1: dict, levels: int | None = None, previous: "LightFieldPair | None" = None):
        self.views = [v for v in images0 if v in images1]
        if not self.views:
            raise LfusdError("ray flow needs the views at t and t+1")
        shapes = {np.shape(images0[v])[:2] for v in self.views} | {np.shape(images1[v])[:2] for v in self.views}
        if len(shapes) != 1:
            raise LfusdError(f"ray flow needs every image at one size, got {sorted(shapes)}")
        h, w = shapes.pop()
        self.shape = (h, w)
        self.levels = max(1, int(np.floor(np.log2(min(h, w) / 16))) + 1) if levels is None else levels
        if previous is not None and previous.views == self.views and previous.levels == self.levels and previous.shape == self.shape:
            self.I0, self.S0 = previous.I1, previous.S1
        else:
            self.I0 = self._pyramid(images0)
            self.S0 = [np.stack([_spline(a) for a in lvl]) for lvl in self.I0]
        self.I1 = self._pyramid(images1)
        self.S1 = [np.stack([_spline(a) for a in lvl]) for lvl in self.I1]
        self.G1 = [np.stack([np.concatenate(_gradients(a), -1) for a in lvl]) for lvl in self.I1]

    def _pyramid(self, images: dict) -> list[list[np.ndarray]]:
        pyr = [[_grey_stack(images[s]) for s in self.views]]
        for _ in range(self.levels - 1):
            pyr.append([_pyr_down(a) for a in pyr[-1]])
        return pyr


def _level_step(pair: LightFieldPair, lvl: int, d, rel, K, V, solver, window, lam, sigma_d, robust, iterations):
    """Gauss-Newton iterations of the ray flow at one pyramid level; returns V (H,W,3), baseline units."""
    from . import _baselines_numba as nb

    fx, fy, cx, cy = K
    h, w = d.shape
    v, u = np.mgrid[0:h, 0:w].astype(np.float64)
    dd = np.maximum(d, 1e-3)  # a point at (numerically) infinite depth: its rays do not move; V is left to the regulariser
    Z = fx / dd
    X, Y = (u - cx) / fx * Z, (v - cy) / fy * Z
    # the rays of the reference pixel's point in every view at t: its light-field correspondence
    S0, S1, G1 = pair.S0[lvl], pair.S1[lvl], pair.G1[lvl]
    L0 = np.empty(S0.shape)
    in0 = np.empty((len(rel), h, w), bool)
    for s in range(len(rel)):
        us, vs = u - d * rel[s, 0], v - d * rel[s, 1]
        L0[s] = nb.cubic_sample(S0[s], us, vs)
        in0[s] = (us >= 0) & (us <= w - 1) & (vs >= 0) & (vs <= h - 1)
    if solver == "global":
        wr, wd = _edge_weights(d, sigma_d)
    for _ in range(iterations):
        # every view's ray of the moved point at t+1, its ray flow equation per channel, Cauchy-weighted
        # (occluded rays disagree), summed into 3x3 normal equations per pixel
        A, b = nb.ray_normal_equations(S1, G1, L0, in0, rel, X, Y, Z, V, fx, fy, cx, cy, robust)
        scale = max(float(np.mean(np.trace(A, axis1=-2, axis2=-1))) / 3.0, 1e-12)
        if window > 1:
            # V constant over the window: each neighbour q's equations, linearised at its own V_q,
            # are moved to V_p: sum_q A_q V_p = sum_q (A_q V_q - b_q) (the box filter averages)
            AV = np.einsum("hwij,hwj->hwi", A, V)
            A = _box(A.reshape(h, w, 9), window).reshape(h, w, 3, 3)
            b = np.einsum("hwij,hwj->hwi", A, V) - _box(AV - b, window)  # the normal equations A (V + delta) = box(AV - b)
        if solver == "local":
            delta = nb.solve3(A, -b, np.full((h, w), 1e-6 * scale))
        else:
            # (A + lam L + eps) delta = -b - lam L V with the structure-aware Laplacian L, by conjugate
            # gradients (symmetric positive definite) with each pixel's 3x3 block inverted as
            # preconditioner: a direct factorisation costs seconds at 128x128
            rhs = -b.reshape(-1) - nb.smooth_apply(V.reshape(-1), wr, wd, lam * scale)
            sol = nb.block_cg(np.ascontiguousarray(A.reshape(h * w, 3, 3)), wr, wd, lam * scale, 1e-6 * scale, rhs, 1e-5, 200)  # Gauss-Newton refines the rest
            delta = sol.reshape(h, w, 3)
        V = V + delta
        if float(np.max(np.abs(delta))) < 1e-4:
            break
    return V


def ray_flow(images0: dict, images1: dict, offsets: dict, ref_view, K, disparity, solver: str = "global", window: int = 7,
             smoothness: float = 1.0, levels: int | None = None, iterations: int = 5, robust: float = 0.1, edge: float = 0.3, global_window: int = 7, pair: LightFieldPair | None = None) -> np.ndarray:
    """3-D displacement of the point seen at every pixel of ``ref_view`` between t and t+1, in the
    reference camera's frame (OpenCV axes, units of the baseline), as if the rig stood still.

    ``images0`` / ``images1``: {view: (H,W,3) image} at t and t+1 (any views of a planar, parallel rig);
    ``offsets``: {view: (sx, sy)} in baselines; ``K``: the 3x3 intrinsics shared by the views;
    ``disparity``: (H,W) of the reference view at t, px per baseline step (d = f b / z).
    ``solver``: 'local' (window ``window``) or 'global' (data aggregated over ``global_window``;
    ``smoothness`` lambda, relative to the mean data term; ``edge``: px of disparity difference over
    which the smoothness weight falls by 1/e).
    ``robust``: the Cauchy scale of the temporal difference, in [0, 1] intensity.
    ``pair``: the :class:`LightFieldPair` of these images, when one was built for another reference view.
    Returns (H,W,3) float64.
    """
    if solver not in SOLVERS:
        raise LfusdError(f"unknown ray flow solver {solver!r}; use one of {', '.join(SOLVERS)}")
    views = [v for v in images0 if v in images1]
    if not views or ref_view not in offsets:
        raise LfusdError("ray flow needs the views at t and t+1 and the reference view's offset")
    K = np.asarray(K, np.float64)
    d = np.asarray(disparity, np.float64)
    h, w = d.shape
    if any(np.shape(images0[s])[:2] != (h, w) or np.shape(images1[s])[:2] != (h, w) for s in views):
        raise LfusdError(f"ray flow needs every image at the disparity's size {w}x{h}")
    if pair is None or pair.views != views or (levels is not None and pair.levels != levels):
        pair = LightFieldPair(images0, images1, levels)
    levels = pair.levels
    rel = np.array([(offsets[s][0] - offsets[ref_view][0], offsets[s][1] - offsets[ref_view][1]) for s in views], np.float64).reshape(-1, 2)
    pyr = [(d, (K[0, 0], K[1, 1], K[0, 2], K[1, 2]))]
    for _ in range(levels - 1):
        dl, (fx, fy, cx, cy) = pyr[-1]
        dl_small = _pyr_down(dl[..., None])[..., 0] * 0.5  # disparity is in pixels: it halves with the image
        # pyrDown's pixel x is the blurred source pixel 2x: x' = x / 2
        pyr.append((dl_small, (fx / 2, fy / 2, cx / 2, cy / 2)))
    V = np.zeros(pyr[-1][0].shape + (3,))
    for lvl in range(levels - 1, -1, -1):
        dl, Kl = pyr[lvl]
        if V.shape[:2] != dl.shape:
            import cv2

            # V is in baselines (no rescale) and smooth: resize's half-pixel grid, a quarter pixel
            # off pyrDown's, only shifts the next level's starting point, which it then refines
            V = np.dstack([cv2.resize(V[..., i], (dl.shape[1], dl.shape[0]), interpolation=cv2.INTER_LINEAR) for i in range(3)])
        V = _level_step(pair, lvl, dl, rel, Kl, V, solver, window if solver == "local" else global_window, smoothness, edge * 0.5**lvl, robust, iterations)
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

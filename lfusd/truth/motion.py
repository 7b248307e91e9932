"""Motion ground truth from raw render passes: optical flow, scene flow, disparity change, masks.

No Blender. Inputs are the raw passes of one view at frames t, t+1 and t-1 (:class:`RawPasses`);
outputs follow docs/CONVENTIONS.md exactly (:data:`MOTION_KEYS`). Two backends compute the
same thing: a NumPy reference (vectorised) and a compiled one-pass kernel
(``lfusd.truth._motion_numba``, the default; numba is a required dependency): for a 1024x1024 view with both neighbours about
1.4 s against 27 ms (2 threads) or 50 ms (1 thread); see benchmarks/bench_flow.py.

Which route produces which key
------------------------------
*Exact route* (used at every pixel where ``next_position`` / ``prev_position`` is finite: an AOV
holding the world position at t+1 / t-1 of the very surface point seen at t):

- ``flow_fwd`` = projection of ``next_position`` with the camera at t+1, minus the projection of
  ``position`` (the point sampled) with the camera at t;
- ``scene_flow`` = ``next_position`` - ``position`` (``position`` from the position pass, or the
  depth back-projected when the pass is absent);
- ``disparity_change`` = f*b/z(t+1) - f*b/z(t), z(t+1) the point's depth in the camera at t+1;
- ``flow_bwd`` likewise from ``prev_position`` and the camera at t-1.
These are defined for points that are hidden or off-image at t+1 too: ``valid_fwd`` covers every
foreground pixel of a frame that has a next frame, and ``occlusion_fwd`` says which are hidden.

*Vector-plus-depth route* (the baseline, where no position AOV is given):

- ``flow_fwd`` = (-Z, +W) and ``flow_bwd`` = (X, -Y) of Blender's vector pass (channels X, Y =
  previous - current, Z, W = current - next, raster pixels, y up). The vector pass is the motion
  of the surface point itself, so these are exact for hidden points as well;
- ``scene_flow`` and ``disparity_change`` need the point's depth at t+1, read from frame t+1's
  depth at (u', v') = (u+du, v+dv): inverse depth extrapolated to (u', v') from each of the four
  pixels around it with their one-sided slopes (1/z is affine in u, v on a plane, so on a planar
  patch all four agree and the value is exact). It is defined only where the point is visible at
  t+1, all four pixels show its instance and agree to ``DEPTH_REL`` (so not across a crease or an
  edge): there ``valid_fwd`` is set. Elsewhere ``flow_fwd`` keeps the vector value and
  ``scene_flow`` / ``disparity_change`` are 0. ``valid_bwd`` is foreground & a previous frame
  exists (flow_bwd is the only backward key).

Occlusion
---------
With the other frame's rendered triangles (``occluders``: render-video writes them per frame,
``geometry.npz``), occlusion is exact ray-cast visibility of each valid pixel's point at t+1 / t-1
(:mod:`lfusd.truth.visibility`; the definition and its tie rule are in docs/CONVENTIONS.md).
Unknown motion (a NaN ``next_position`` / ``prev_position`` where the AOV exists: the worker's
mark of a mesh whose topology changed) makes the pixel invalid with zero flow, never guessed.

Without triangles (datasets rendered before lfusd wrote them, and the vector route) an image-space
test decides, exact inside planar patches and within about half a pixel of edges:
``occlusion_fwd`` is set on a foreground pixel unless its point at t+1, at (u', v'):

1. projects inside the image (u' in [-0.5, W-0.5], v' in [-0.5, H-0.5]) and in front of the camera;
2. the pixel of frame t+1 nearest (u', v') shows the point's instance, or a surface behind the
   point (then the point sits on a silhouette in front of what that pixel centre sees);
3. forward-backward consistency holds from at least one of the four pixels around (u', v') on
   the point's instance (within ``FB_ABS`` + ``FB_REL`` * |flow_fwd|); and
4. (exact route only) the depth test holds from that same pixel within ``DEPTH_REL``.
On the last frame (no ``nxt``) every forward key is 0 and masked invalid, likewise backward keys
on the first frame (no ``prv``).
"""

from __future__ import annotations

import logging

import numpy as np

from .. import cpu_account
from ..camera import Camera, backproject, pixel_grid, project
from ..data.passes import RawPasses  # noqa: F401  (the input of derive_motion, re-exported)
from ..errors import LfusdError
from ..keys import BACKGROUND_DEPTH, KEYS, MOTION, names
from ..camera import has_lens, point_disparity, project_imaged

log = logging.getLogger(__name__)

# what derive_motion derives: every motion key but a camera effect's (blur: lfusd.truth.blur, added by lfusd.truth.derive)
MOTION_KEYS = tuple(k for k in names(MOTION) if KEYS[k].effect is None)
FB_ABS = 0.05  # px: forward-backward consistency slack
FB_REL = 0.01  # fraction of the flow magnitude added to the slack
DEPTH_REL = 1e-3  # relative inverse-depth slack of the depth test
EDGE_REL = 0.5  # a relative inverse-depth jump above this between neighbours is a depth edge


def _check(p: RawPasses, what: str, shape: tuple[int, int] | None = None) -> tuple[int, int]:
    if p.depth.ndim != 2:
        raise LfusdError(f"{what}: depth has shape {p.depth.shape}; expected (H, W)")
    hw = shape or p.shape
    if min(hw) < 2:
        raise LfusdError(f"{what}: the view is {hw[1]}x{hw[0]} pixels; motion needs at least 2x2")
    for key in ("depth", "vector", "position", "instance", "next_position", "prev_position"):
        a = getattr(p, key)
        want = KEYS[key].full_shape(*hw)
        if a is not None and tuple(a.shape) != want:
            raise LfusdError(f"{what}: {key} has shape {tuple(a.shape)} but the view is {hw[1]}x{hw[0]}; expected {want} (re-render it)")
    return hw


def foreground(depth: np.ndarray) -> np.ndarray:
    """Pixels that see a surface."""
    return np.isfinite(depth) & (depth > 0) & (depth < BACKGROUND_DEPTH)


def world_position(p: RawPasses, fg: np.ndarray) -> np.ndarray:
    """World position of every pixel at t: the position pass where finite, else back-projected depth."""
    h, w = p.shape
    u, v = pixel_grid(h, w)
    z = np.where(fg, p.depth, 0).astype(np.float32)
    back = backproject(u, v, z, p.camera)
    if p.position is None:
        return back
    pos = np.asarray(p.position, dtype=np.float32)
    return np.where(np.isfinite(pos), pos, back)


def _inv_depth(depth: np.ndarray) -> np.ndarray:
    with np.errstate(divide="ignore"):
        inv = np.where(foreground(depth), 1.0 / depth.astype(np.float32), 0.0)
    return inv.astype(np.float32)


def _forward_vector(vec: np.ndarray) -> np.ndarray:
    return np.stack([-vec[..., 2], vec[..., 3]], axis=-1).astype(np.float32)


def _backward_vector(vec: np.ndarray) -> np.ndarray:
    return np.stack([vec[..., 0], -vec[..., 1]], axis=-1).astype(np.float32)


def _slope_bounds(img: np.ndarray, smooth: np.ndarray, axis: int) -> tuple[np.ndarray, np.ndarray]:
    """Lower and upper per-pixel slope of ``img`` (H,W,C) along ``axis`` from its two one-sided differences.

    ``smooth`` (H,W) minus one along ``axis``: whether neighbours lie on one surface (same
    instance, no depth edge). Differences across an edge are ignored; with one usable side its
    slope is both bounds, with none both are 0. At a crease the two sides differ and the bounds
    span both slopes, so extrapolation from a pixel on either face covers the truth.
    """
    d = np.where(np.expand_dims(smooth, -1), np.diff(img, axis=axis), np.nan)
    pad = [(0, 0)] * img.ndim
    pad[axis] = (1, 0)
    back = np.pad(d, pad, constant_values=np.nan)  # img[i] - img[i-1]
    pad[axis] = (0, 1)
    fwd = np.pad(d, pad, constant_values=np.nan)  # img[i+1] - img[i]
    back = np.where(np.isnan(back), fwd, back)
    fwd = np.where(np.isnan(fwd), back, fwd)
    lo = np.nan_to_num(np.fmin(back, fwd), nan=0.0).astype(np.float32)
    hi = np.nan_to_num(np.fmax(back, fwd), nan=0.0).astype(np.float32)
    return lo, hi


class _Target:
    """The four pixels of another frame around sub-pixel points, with first-order extrapolation from each."""

    def __init__(self, x, y, inst_self, inst_other: np.ndarray, inv_other: np.ndarray, h: int, w: int):
        x0 = np.clip(np.floor(x), 0, max(w - 2, 0)).astype(np.int64)
        y0 = np.clip(np.floor(y), 0, max(h - 2, 0)).astype(np.int64)
        xs = np.stack([x0, x0 + 1, x0, x0 + 1])
        ys = np.stack([y0, y0, y0 + 1, y0 + 1])
        self.dx, self.dy = (x - xs).astype(np.float32), (y - ys).astype(np.float32)  # (4, N)
        self.index = ys * w + xs
        self.same = inst_other.ravel()[self.index] == inst_self  # (4, N)
        nearest = np.argmin(self.dx**2 + self.dy**2, axis=0)
        self.nearest = np.take_along_axis(self.index, nearest[None], 0)[0]
        self.nearest_same = np.take_along_axis(self.same, nearest[None], 0)[0]
        # Neighbour pairs on one surface (same instance, no inverse-depth jump), along x then y.
        self.smooth = []
        for lo_nb, hi_nb, axis in (
            (inv_other[:, :-1], inv_other[:, 1:], 1),
            (inv_other[:-1], inv_other[1:], 0),
        ):
            jump_ok = np.abs(hi_nb - lo_nb) <= EDGE_REL * np.minimum(lo_nb, hi_nb)
            self.smooth.append((np.diff(inst_other, axis=axis) == 0) & jump_ok)

    def interval(self, img: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """Bounds of ``img`` (H,W,C) at the points as seen from each corner: (lo, hi, ext_lo, ext_hi), each (4,N,C).

        ext_lo/ext_hi extrapolate the corner's value with its two one-sided slopes (equal on a
        plane, so the bounds meet at the exact value there). lo/hi also reach to the values of
        the other same-instance corners, so a point between pixels of two faces (a crease seen
        edge-on, a face thinner than a pixel) is bracketed by them.
        """
        c = img.shape[-1]
        i = self.index
        vals = img.reshape(-1, c)[i]
        ext_lo = ext_hi = vals
        for axis, off in ((1, self.dx), (0, self.dy)):
            glo, ghi = _slope_bounds(img, self.smooth[0 if axis == 1 else 1], axis)
            a = glo.reshape(-1, c)[i] * off[..., None]
            b = ghi.reshape(-1, c)[i] * off[..., None]
            ext_lo, ext_hi = ext_lo + np.minimum(a, b), ext_hi + np.maximum(a, b)
        same = self.same[..., None]
        env_lo = np.where(same, vals, np.inf).min(axis=0)
        env_hi = np.where(same, vals, -np.inf).max(axis=0)
        return np.minimum(ext_lo, env_lo), np.maximum(ext_hi, env_hi), ext_lo, ext_hi


def _visibility_numpy(x, y, fl, z_exp, exact, inst_cur, inst_other, inv_other, back):
    """Occlusion tests of the module docstring for points (x, y) in the other frame (NumPy reference).

    Returns (visible, vector_ok, inv_pt) per point: visible at the other frame, whether the
    vector-plus-depth route may trust its depth there, and the point's inverse depth there.
    """
    h, w = inv_other.shape
    inside = (x >= -0.5) & (x <= w - 0.5) & (y >= -0.5) & (y <= h - 0.5) & ~(z_exp <= 0)
    tg = _Target(np.clip(x, -1, w), np.clip(y, -1, h), inst_cur, inst_other, inv_other, h, w)
    slack = (FB_ABS + FB_REL * np.sqrt((fl**2).sum(axis=1)))[None, :, None]
    lo, hi, _, _ = tg.interval(back)
    fb_ok = ((-fl >= lo - slack) & (-fl <= hi + slack)).all(axis=2)  # (4, N)
    lo, hi, ext_lo, ext_hi = (a[..., 0] for a in tg.interval(inv_other[..., None]))
    with np.errstate(divide="ignore", invalid="ignore"):
        inv_exp = (1.0 / z_exp).astype(np.float32)
        tol = DEPTH_REL * inv_exp
        depth_ok = ((inv_exp >= lo - tol) & (inv_exp <= hi + tol)) | ~exact
    agree = tg.same & fb_ok & depth_ok  # (4, N)
    # Vector route: the point's inverse depth extrapolated from the four corners; on a planar
    # patch every corner's two slopes meet at the exact value. Near a crease or an edge they
    # disagree, and the route leaves the point undefined (not "sharp").
    inv_vec = 0.5 * (ext_lo.min(axis=0) + ext_hi.max(axis=0))
    sharp = agree.all(axis=0) & (ext_hi.max(axis=0) - ext_lo.min(axis=0) <= DEPTH_REL * inv_vec)
    inv_pt = np.where(exact, inv_exp, inv_vec)
    # The pixel nearest the point must show its instance, or a surface behind it (the point is
    # then at a silhouette, in front of what the pixel centre sees); a nearer surface hides it.
    behind = inv_other.ravel()[tg.nearest] < inv_pt * (1 - DEPTH_REL)
    visible = inside & (tg.nearest_same | behind) & agree.any(axis=0)
    # Vector route values are trusted only away from instance edges and creases.
    vector_ok = ~exact & visible & sharp
    return visible, vector_ok, inv_pt.astype(np.float32)


def _direction(cur: RawPasses, other: RawPasses, fg: np.ndarray, other_position, forward: bool, pos_t: np.ndarray):
    """Flow towards ``other``, the point's depth there where knowable, occlusion and masks.

    Returns (flow (H,W,2), z_other (N,), exact (N,), visible (N,), vector_ok (N,), idx (N,), (x, y)),
    all per foreground pixel (flat indices ``idx``).
    """
    h, w = cur.shape
    u, v = pixel_grid(h, w)
    idx = np.flatnonzero(fg)
    flow = _forward_vector(cur.vector) if forward else _backward_vector(cur.vector)
    flow[~fg] = 0
    fl = flow.reshape(-1, 2)[idx]
    z_exp = np.full(idx.size, np.nan, np.float32)
    exact = np.zeros(idx.size, bool)
    if other_position is not None:
        P1 = np.asarray(other_position, dtype=np.float32).reshape(-1, 3)[idx]
        exact = np.isfinite(P1).all(axis=1)
        pu, pv, pz = project(P1[exact].astype(np.float64), other.camera)
        if has_lens(other.camera):  # through a lens: a point beyond its fold has no image at all (invalid, counted)
            imaged = project_imaged(P1[exact].astype(np.float64), other.camera)[3]
            if not imaged.all():
                log.debug("%d points beyond the lens's fold at the %s frame: invalid", int((~imaged).sum()), "next" if forward else "previous")
                exact[np.flatnonzero(exact)[~imaged]] = False
                pu, pv, pz = pu[imaged], pv[imaged], pz[imaged]
        # From the point that was sampled, not the pixel centre: on a sliver triangle Blender's
        # sample lands off the pixel's ray, and a static point must get zero flow.
        u0, v0, _ = project(pos_t.reshape(-1, 3)[idx][exact].astype(np.float64), cur.camera)
        fl[exact, 0], fl[exact, 1] = pu - u0, pv - v0
        fl[~exact] = 0  # unknown (the mesh changed its topology): flagged invalid, never guessed
        z_exp[exact] = pz
        flow.reshape(-1, 2)[idx] = fl
    x = u.ravel()[idx] + fl[:, 0]
    y = v.ravel()[idx] + fl[:, 1]
    inst_cur = (cur.instance if cur.instance is not None else fg.astype(np.int32)).ravel()[idx]
    inst_other = other.instance if other.instance is not None else foreground(other.depth).astype(np.int32)
    inv_other = _inv_depth(other.depth)
    # Forward-backward consistency against the other frame's vector pass pointing back to t.
    back = _backward_vector(other.vector) if forward else _forward_vector(other.vector)
    visible, vector_ok, inv_pt = _visibility_numpy(
        x.astype(np.float32), y.astype(np.float32), fl, z_exp, exact, inst_cur.astype(np.int32),
        np.ascontiguousarray(inst_other, dtype=np.int32), inv_other, np.ascontiguousarray(back),
    )
    if other_position is not None:
        vector_ok[:] = False  # the position AOV is the route; where it is NaN the motion is unknown
    with np.errstate(divide="ignore", invalid="ignore"):
        z_exp[vector_ok] = 1.0 / inv_pt[vector_ok]
    return flow, z_exp, exact, visible, vector_ok, idx, (x, y)


# The compiled kernels (same algorithm as the NumPy code, one pass per pixel); numba is required.
from . import _motion_numba as _flow_numba  # noqa: E402

BACKEND = "numba"


_ANNOUNCED = False


def announce_compile() -> None:
    """Say once, in one line, that the motion kernels are being compiled when numba has not cached
    them yet: the first derivation otherwise sits silent for about two minutes."""
    global _ANNOUNCED
    if _ANNOUNCED:
        return
    _ANNOUNCED = True
    if not _flow_numba.kernels_cached():
        import logging

        logging.getLogger(__name__).warning("compiling the motion kernels (numba, once per installation, about 2 minutes); "
                                            "later runs load them from numba's cache")


def compile_kernels() -> bool:
    """Compile numba's motion kernels into its on-disk cache (scripts/setup.sh calls this, so a
    fresh clone's first render-video does not wait minutes); whether anything was compiled."""
    if _flow_numba.kernels_cached():
        return False
    load_kernels()
    return True


def load_kernels() -> None:
    """Load numba's motion kernels (from its cache, or compiling them) with a derivation of a 4x4 view."""
    if _flow_numba is None:
        return
    cam = Camera(np.array([[4.0, 0, 1.5], [0, 4.0, 1.5], [0, 0, 1]]), np.eye(4))
    depth = np.full((4, 4), 2.0, np.float32)
    pos = backproject(*pixel_grid(4, 4), depth, cam).astype(np.float32)
    raw = RawPasses(depth, np.zeros((4, 4, 4), np.float32), cam, pos, np.ones((4, 4), np.int32), pos, pos)
    derive_motion(raw, raw, raw, baseline=0.1, backend="numba")
    from .visibility import Occluders  # and the exact-occlusion and mixed kernels, on one triangle

    from .visibility import StaticMemo

    # one triangle in place and one moving: both parts of exact occlusion and mixed, and the memo
    tris = np.array([[0, 1, 2], [3, 4, 5]])
    here = np.array([[-9, -9, 3], [9, -9, 3], [0, 9, 3], [-1, -1, 2], [1, -1, 2], [0, 1, 2]], np.float32)
    moved = here.copy()
    moved[3:, 2] += 0.25
    frames = [Occluders(v, tris, np.array([1, 2], np.int32)) for v in (moved, here, moved)]
    memo = StaticMemo(0)
    for _ in range(2):
        derive_motion(raw, raw, raw, baseline=0.1, backend="numba", occluders=dict(zip(("prev", "here", "next"), frames)), memo=memo)


def derive_motion(
    cur: RawPasses,
    nxt: RawPasses | None = None,
    prv: RawPasses | None = None,
    baseline: float | None = None,
    backend: str | None = None,
    occluders: dict | None = None,
    memo=None,
) -> dict[str, np.ndarray]:
    """All motion keys of CONVENTIONS.md for one view at frame t (see the module docstring).

    ``nxt`` / ``prv``: the same view's raw passes at t+1 / t-1 (None on the last / first frame).
    ``baseline``: the rig baseline b in metres for disparity d = f_px * b / z (K[0,0] is f_px);
    without it ``disparity_change`` is 0 and only the other keys are meaningful.
    ``backend``: 'numba' (compiled, the default) or 'numpy' (reference).
    ``occluders``: {"next": Occluders, "prev": Occluders, "here": Occluders}, the triangles of t+1 /
    t-1 / t as rendered (lfusd.truth.visibility): occlusion is then exact ray-cast visibility, not
    the image-space test, and ``mixed`` (one ray per pixel corner) is computed from "here".
    ``memo``: the view's lfusd.truth.visibility.StaticMemo, which keeps the answers of the triangles
    that stay in place from frame to frame (same results, fewer rays).
    """
    backend = backend or BACKEND
    if any(other is not None and has_lens(other.camera) for other in (cur, nxt, prv)):
        # the compiled kernels project through a pinhole: a distorted view takes the NumPy route, which
        # projects with lfusd.camera (through the lens), and casts whole scenes (no memo, no parts)
        backend, memo = "numpy", None
    if backend not in ("numba", "numpy"):
        raise LfusdError(f"flow backend {backend!r} is not available; use 'numba' or 'numpy'")
    hw = _check(cur, "frame t")
    # directions whose occlusion is exact ray-cast visibility (the image-space test is then not needed)
    exact = tuple(key for key, other, opos in (("next", nxt, cur.next_position), ("prev", prv, cur.prev_position))
                  if other is not None and opos is not None and (occluders or {}).get(key) is not None)
    for key, other, what in (("next", nxt, "frame t+1"), ("prev", prv, "frame t-1")):
        if other is None:
            continue
        if backend == "numba" and key in exact:  # only its camera is used: its images stay undecoded (LazyRawPasses)
            if tuple(other.shape) != hw:
                raise LfusdError(f"{what}: the view is {other.shape[1]}x{other.shape[0]} but frame t is {hw[1]}x{hw[0]} (re-render it)")
        else:
            _check(other, what, hw)
    h, w = hw
    fg = foreground(cur.depth)
    out = {k: np.zeros(KEYS[k].full_shape(h, w), KEYS[k].dtype) for k in MOTION_KEYS}
    if nxt is None and prv is None:
        return out
    fb = float(cur.camera.K[0, 0]) * float(baseline) if baseline else 0.0
    with cpu_account.phase("derive"):
        if backend == "numba":
            _derive_numba(cur, nxt, prv, fb, out, exact)
        else:
            _derive_numpy(cur, nxt, prv, fb, fg, out)
    here = (occluders or {}).get("here")
    with cpu_account.phase("occluders"):
        # without a memo to keep the static part's answers, the whole scene in one cast is cheaper
        parts = _parts(occluders or {}) if memo is not None else {}
    for key, other, opos in (("next", nxt, cur.next_position), ("prev", prv, cur.prev_position)):
        if key in exact:
            with cpu_account.phase("visibility"):
                exact_occlusion(cur, other, opos, occluders[key], out, fwd=key == "next", parts=parts.get(key), memo=memo)
    if here is not None:
        from .visibility import mixed_footprint

        with cpu_account.phase("mixed"):
            out["mixed"] = mixed_footprint(cur.camera, h, w, here, occluders.get("next"), nxt.camera if nxt is not None else None,
                                           parts=parts.get("here"), memo=memo)
    return out


def _parts(occluders: dict) -> dict:
    """Each frame's triangles split into what stays in place and what moves (lfusd.truth.visibility.Parts):
    t+1's and t-1's by t's, t's by t+1's (else t-1's)."""
    here = occluders.get("here")
    if here is None:
        return {}
    parts = {key: occluders[key].parts(here) for key in ("next", "prev") if occluders.get(key) is not None}
    ref = occluders.get("next") or occluders.get("prev")
    if ref is not None:
        parts["here"] = here.parts(ref)
    return parts


def exact_occlusion(cur: RawPasses, other: RawPasses, other_position: np.ndarray, occluders, out: dict, fwd: bool,
                    parts=None, memo=None) -> None:
    """Replace ``occlusion_fwd`` (``fwd``) or ``occlusion_bwd`` with ray-cast visibility of each valid
    pixel's point at t+1 / t-1 against that frame's rendered triangles (lfusd.truth.visibility)."""
    from .visibility import visible

    sfx = "fwd" if fwd else "bwd"
    known = out[f"valid_{sfx}"]
    h, w = cur.shape
    seen = visible(other_position, known, other.camera, h, w, occluders, parts=parts, memo=memo)
    out[f"occlusion_{sfx}"] = (known.ravel() & ~seen).reshape(h, w)


def _derive_numpy(cur: RawPasses, nxt: RawPasses | None, prv: RawPasses | None, fb: float, fg: np.ndarray, out: dict) -> None:
    """derive_motion's NumPy reference path, writing into ``out``."""
    pos_t = world_position(cur, fg)
    if nxt is not None:
        flow, z1, exact, visible, route, idx, (x, y) = _direction(cur, nxt, fg, cur.next_position, True, pos_t)
        out["flow_fwd"] = flow
        P0 = pos_t.reshape(-1, 3)[idx]
        P1 = np.zeros_like(P0)
        if exact.any():
            P1[exact] = np.asarray(cur.next_position, np.float32).reshape(-1, 3)[idx][exact]
        if route.any():
            P1[route] = backproject(x[route], y[route], z1[route], nxt.camera)
        known = exact | route
        sf = np.where(known[:, None], P1 - P0, 0).astype(np.float32)
        out["scene_flow"].reshape(-1, 3)[idx] = sf
        z0 = cur.depth.ravel()[idx].astype(np.float32)
        with np.errstate(divide="ignore", invalid="ignore"):
            if has_lens(cur.camera) or has_lens(nxt.camera):  # the disparity of a distorted view (docs/CONVENTIONS.md)
                b = fb / float(cur.camera.K[0, 0])
                dc = point_disparity(P1, nxt.camera, b) - point_disparity(P0, cur.camera, b) if fb else np.zeros(len(P0))
                known &= np.isfinite(dc)  # a point either camera does not image has no disparity there
            else:
                dc = fb / z1 - fb / z0
            dc = np.where(known, dc, 0).astype(np.float32)
        out["disparity_change"].ravel()[idx] = dc
        out["valid_fwd"].ravel()[idx] = known
        out["occlusion_fwd"].ravel()[idx] = ~visible & (exact if cur.next_position is not None else True)
    if prv is not None:
        flow, _, exact, visible, _, idx, _ = _direction(cur, prv, fg, cur.prev_position, False, pos_t)
        out["flow_bwd"] = flow
        known = exact if cur.prev_position is not None else np.ones(idx.size, bool)
        out["valid_bwd"].ravel()[idx] = known
        out["occlusion_bwd"].ravel()[idx] = ~visible & known


def _derive_numba(cur: RawPasses, nxt: RawPasses | None, prv: RawPasses | None, fb: float, out: dict,
                  exact: tuple[str, ...] = ()) -> None:
    """derive_motion's compiled path: one fused pass per direction, writing into ``out``. ``exact``:
    the directions ("next", "prev") whose occlusion the caller replaces with ray-cast visibility,
    so the kernel skips the image-space test there."""
    k = _flow_numba
    f32 = lambda a: np.ascontiguousarray(a, dtype=np.float32)  # noqa: E731
    none3 = np.zeros((1, 1, 3), np.float32)
    depth = f32(cur.depth)
    has_pos = cur.position is not None
    here = k.Here(depth, f32(cur.vector), f32(cur.position) if has_pos else none3,
                  np.ascontiguousarray(cur.instance if cur.instance is not None else foreground(depth), dtype=np.int32))
    R, C = cur.camera.world_to_cam()
    C = np.ascontiguousarray(C, np.float64)  # one array type whatever the pose came from: one compiled signature
    A_cur = R.T @ np.linalg.inv(np.asarray(cur.camera.K, np.float64))
    M_cur = np.asarray(cur.camera.K, np.float64) @ R
    for other, opos, key in ((nxt, cur.next_position, "next"), (prv, cur.prev_position, "prev")):
        if other is None:
            continue
        forward = key == "next"
        image_occlusion = opos is None or key not in exact
        if image_occlusion:
            inv_o, back_o = k.inverse_depth_and_back(f32(other.depth), f32(other.vector), forward, BACKGROUND_DEPTH)
            inst_o = np.ascontiguousarray(other.instance if other.instance is not None else inv_o > 0, dtype=np.int32)
        else:  # the exact route at every pixel, occlusion from the caller's rays: the other frame's images are not read
            inv_o, back_o, inst_o = np.zeros((1, 1), np.float32), np.zeros((1, 1, 2), np.float32), np.zeros((1, 1), np.int32)
        Ro, Co = other.camera.world_to_cam()
        Co = np.ascontiguousarray(Co, np.float64)
        Ko = np.asarray(other.camera.K, np.float64)
        sfx = "fwd" if forward else "bwd"
        k.direction(
            here,
            k.Other(f32(opos) if opos is not None else none3, inst_o, inv_o, back_o),
            k.Cameras(A_cur, C, M_cur, Ko @ Ro, Ro[2].copy(), Co, Ro.T @ np.linalg.inv(Ko)),
            k.Settings(has_pos, opos is not None, forward, image_occlusion, fb, BACKGROUND_DEPTH, FB_ABS, FB_REL, DEPTH_REL, EDGE_REL),
            k.Out(out[f"flow_{sfx}"], out["scene_flow"], out["disparity_change"], out[f"valid_{sfx}"], out[f"occlusion_{sfx}"]),
        )

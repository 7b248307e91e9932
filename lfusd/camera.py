"""The camera model and light-field rig geometry, in pure NumPy (no USD, no Blender).

:class:`Camera` (pinhole: OpenCV K and cam_to_world) with :func:`project`, :func:`backproject`,
:func:`ray_directions` and :func:`pixel_grid` is the one camera model of lfusd; :class:`RigSpec`
places a grid of such cameras. Frames follow docs/CONVENTIONS.md: camera poses are OpenCV (x right, y down, z forward),
world is Z up, views are (row, col) row-major with (0, 0) top-left seen from behind the rig.

Spacings (offsets of a view from the centre, in units of the baseline ``b``): counting the
gaps between neighbouring cameras outward from the centre as j = 1, 2, ..., gap j is
``b`` (uniform), ``j*b`` (linear), ``b/j`` (inverse) or ``2**(j-1)*b`` (exponential). With an
even count the innermost gap straddles the centre, so the two middle views sit at -/+ half of
gap 1.
"""

from __future__ import annotations

import math
import re
from dataclasses import asdict, dataclass

import numpy as np

from .errors import LfusdError

SPACINGS = ("uniform", "linear", "inverse", "exponential")
LAYOUTS = ("plane", "sphere")
AXES = ("parallel", "converge")

# Beyond these a rig is a mistake more often than a plan (authoring a million cameras takes
# hours); `--force` lifts them. 64x64 views; 16384x16384 pixels (Blender's render result alone
# is about 50 GB there).
MAX_VIEWS = 4096
MAX_PIXELS = 16384 * 16384


def check_rig_size(grid: tuple[int, int], resolution: tuple[int, int] | None, force: bool = False) -> None:
    """Refuse, up front, a grid of more than MAX_VIEWS views or a view of more than MAX_PIXELS pixels."""
    if force:
        return
    rows, cols = grid
    if rows * cols > MAX_VIEWS:
        raise LfusdError(f"--grid {rows}x{cols} is {rows * cols} views, more than {MAX_VIEWS} per rig; use a smaller grid or pass --force")
    if resolution and resolution[0] * resolution[1] > MAX_PIXELS:
        w, h = resolution
        raise LfusdError(f"--resolution {w}x{h} is {w * h / 1e6:.0f} Mpixel per view, more than {MAX_PIXELS / 1e6:.0f}; "
                         "use a smaller resolution or pass --force")

View = tuple[int, int]


@dataclass(frozen=True)
class RigSpec:
    """Everything that defines a light-field rig; distances in metres, lens in millimetres."""

    name: str = "rig"
    rows: int = 9
    cols: int = 9
    baseline: float = 0.125
    focal_length_mm: float = 39.0
    sensor_mm: float = 36.0
    width: int = 1024
    height: int = 1024
    at: tuple[float, float, float] = (0.0, -10.0, 1.5)
    look_at: tuple[float, float, float] = (0.0, 0.0, 1.5)
    spacing: str = "uniform"
    layout: str = "plane"
    radius: float | None = None
    axes: str = "parallel"

    def __post_init__(self) -> None:
        validate(self)

    def to_dict(self) -> dict:
        d = asdict(self)
        d["at"], d["look_at"] = list(self.at), list(self.look_at)
        return d

    @classmethod
    def from_dict(cls, d: dict) -> "RigSpec":
        d = dict(d)
        d["at"], d["look_at"] = tuple(d["at"]), tuple(d["look_at"])
        return cls(**d)

    # -- grid -------------------------------------------------------------------------
    @property
    def views(self) -> list[View]:
        return [(r, c) for r in range(self.rows) for c in range(self.cols)]

    @property
    def centre_view(self) -> View:
        """The view nearest the rig centre (exactly the centre for odd counts)."""
        return ((self.rows - 1) // 2, (self.cols - 1) // 2)

    @property
    def sphere_radius(self) -> float:
        return float(self.radius) if self.radius else float(np.linalg.norm(np.subtract(self.look_at, self.at)))

    def offsets(self, view: View) -> tuple[float, float]:
        """(sx, sy): the view's offset from the rig centre in units of the baseline (x right, y down)."""
        r, c = view
        return grid_offset(c, self.cols, self.spacing), grid_offset(r, self.rows, self.spacing)

    # -- intrinsics -------------------------------------------------------------------
    @property
    def focal_px(self) -> float:
        """Focal length in pixels; the sensor size is the image width (horizontal fit)."""
        return self.focal_length_mm / self.sensor_mm * self.width

    def intrinsics(self) -> np.ndarray:
        """OpenCV K with pixel centres at integer coordinates (cx = (W-1)/2)."""
        f = self.focal_px
        return np.array([[f, 0.0, (self.width - 1) / 2.0], [0.0, f, (self.height - 1) / 2.0], [0.0, 0.0, 1.0]])

    # -- extrinsics -------------------------------------------------------------------
    def rig_to_world(self) -> np.ndarray:
        """4x4 pose of the rig frame (OpenCV axes, origin at the rig centre, z towards look_at)."""
        return look_at_pose(np.asarray(self.at, float), np.asarray(self.look_at, float))

    def view_in_rig(self, view: View) -> np.ndarray:
        """4x4 OpenCV camera-to-rig transform of one view."""
        sx, sy = self.offsets(view)
        b = self.baseline
        if self.layout == "plane":
            pos = np.array([sx * b, sy * b, 0.0])
            target = np.array([0.0, 0.0, float(np.linalg.norm(np.subtract(self.look_at, self.at)))])
        else:
            # Cameras on a sphere around (0, 0, R), the arc between neighbours equal to gap lengths.
            rad = self.sphere_radius
            # Viewing direction d from the camera to the centre; a camera right of (below) the
            # centre looks left (up), so the angles take the opposite sign of the offsets.
            theta, phi = -sx * b / rad, -sy * b / rad
            centre = np.array([0.0, 0.0, rad])
            d = np.array([math.sin(theta) * math.cos(phi), math.sin(phi), math.cos(theta) * math.cos(phi)])
            pos = centre - rad * d
            target = centre
        if self.axes == "parallel":
            pose = np.eye(4)
            pose[:3, 3] = pos
            return pose
        return look_at_pose(pos, target, up=np.array([0.0, -1.0, 0.0]))

    def cam_to_world(self, view: View) -> np.ndarray:
        """4x4 OpenCV camera-to-world pose of one view at rest (the stage may animate the rig)."""
        return self.rig_to_world() @ self.view_in_rig(view)


def grid_offset(index: int, count: int, spacing: str) -> float:
    """Signed offset of grid index ``index`` (of ``count``) from the centre, in baselines."""
    k = index - (count - 1) / 2.0
    if k == 0:
        return 0.0
    sign = 1.0 if k > 0 else -1.0
    steps = abs(k)
    gap = {
        "uniform": lambda j: 1.0,
        "linear": lambda j: float(j),
        "inverse": lambda j: 1.0 / j,
        "exponential": lambda j: 2.0 ** (j - 1),
    }[spacing]
    if count % 2 == 1:
        return sign * sum(gap(j) for j in range(1, int(round(steps)) + 1))
    # Even count: half of gap 1, then whole gaps 2, 3, ... outward.
    n = int(round(steps - 0.5))
    return sign * (0.5 * gap(1) + sum(gap(j) for j in range(2, n + 2)))


def look_at_pose(eye: np.ndarray, target: np.ndarray, up: np.ndarray | None = None) -> np.ndarray:
    """4x4 OpenCV pose at ``eye`` looking at ``target``; image up follows ``up`` (world +Z by default)."""
    z = np.asarray(target, float) - np.asarray(eye, float)
    n = np.linalg.norm(z)
    if n == 0:
        raise LfusdError("the rig's --at and --look-at are the same point; give a look-at point away from the rig")
    z = z / n
    up = np.array([0.0, 0.0, 1.0]) if up is None else np.asarray(up, float)
    x = np.cross(z, up)
    if np.linalg.norm(x) < 1e-9:  # looking along the up axis: take world +Y as image up instead
        x = np.cross(z, np.array([0.0, 1.0, 0.0]))
    x /= np.linalg.norm(x)
    y = np.cross(z, x)
    pose = np.eye(4)
    pose[:3, 0], pose[:3, 1], pose[:3, 2], pose[:3, 3] = x, y, z, eye
    return pose


def validate(spec: RigSpec) -> None:
    """Raise LfusdError naming the first impossible parameter of a rig."""
    if not spec.name or not spec.name.replace("_", "a").isalnum() or spec.name[0].isdigit():
        raise LfusdError(f"rig name {spec.name!r} is not a valid USD prim name; use letters, digits and _ (not first a digit)")
    for what, v in (("grid rows", spec.rows), ("grid cols", spec.cols), ("resolution width", spec.width), ("resolution height", spec.height)):
        if not isinstance(v, int) or v <= 0:
            raise LfusdError(f"{what} must be a positive integer, got {v!r}")
    for what, v in (("baseline", spec.baseline), ("focal length", spec.focal_length_mm), ("sensor size", spec.sensor_mm)):
        if not (isinstance(v, (int, float)) and math.isfinite(v) and v > 0):
            raise LfusdError(f"{what} must be a positive number, got {v!r}")
    if spec.spacing not in SPACINGS:
        raise LfusdError(f"unknown spacing {spec.spacing!r}; use one of {', '.join(SPACINGS)}")
    if spec.layout not in LAYOUTS:
        raise LfusdError(f"unknown layout {spec.layout!r}; use one of {', '.join(LAYOUTS)}")
    if spec.axes not in AXES:
        raise LfusdError(f"unknown axes {spec.axes!r}; use one of {', '.join(AXES)}")
    if spec.radius is not None and not (math.isfinite(spec.radius) and spec.radius > 0):
        raise LfusdError(f"radius must be a positive number of metres, got {spec.radius!r}")
    if any(not math.isfinite(float(v)) for v in (*spec.at, *spec.look_at)):
        raise LfusdError("--at and --look-at must be finite X,Y,Z numbers")
    if np.allclose(spec.at, spec.look_at):
        raise LfusdError("the rig's --at and --look-at are the same point; give a look-at point away from the rig")
    if spec.layout == "sphere":
        rad = spec.sphere_radius
        half = max(abs(grid_offset(0, spec.cols, spec.spacing)), abs(grid_offset(0, spec.rows, spec.spacing)))
        if half * spec.baseline / rad >= math.pi / 2:
            raise LfusdError(
                f"a {spec.rows}x{spec.cols} spherical rig with baseline {spec.baseline} m spans more than a hemisphere "
                f"of radius {rad:g} m; use a larger --radius or a smaller --baseline"
            )


def parse_grid(text: str) -> tuple[int, int]:
    """'9x9' -> (9, 9); LfusdError unless both are positive integers."""
    return _parse_pair(text, "grid", "RxC, e.g. 9x9")


def parse_resolution(text: str) -> tuple[int, int]:
    """'1024x768' -> (1024, 768) as (width, height)."""
    return _parse_pair(text, "resolution", "WxH, e.g. 1024x1024")


def _parse_pair(text: str, what: str, form: str) -> tuple[int, int]:
    parts = str(text).lower().split("x")
    try:
        a, b = (int(p) for p in parts)
    except ValueError:
        raise LfusdError(f"{what} {text!r} is not {form}") from None
    if a <= 0 or b <= 0:
        raise LfusdError(f"{what} {text!r} must have positive numbers ({form})")
    return a, b


def parse_point(text: str, what: str) -> tuple[float, float, float]:
    """'1,2,3' -> (1.0, 2.0, 3.0)."""
    try:
        x, y, z = (float(p) for p in str(text).split(","))
    except ValueError:
        raise LfusdError(f"{what} {text!r} is not X,Y,Z (three numbers in metres)") from None
    if not all(math.isfinite(v) for v in (x, y, z)):
        raise LfusdError(f"{what} {text!r} must be finite numbers")
    return x, y, z


def parse_frames(text: str, limit: int | None = None) -> list[int]:
    """'1-5,8' -> [1, 2, 3, 4, 5, 8]: frames N, inclusive ranges A-B and comma lists of both, sorted.
    Time codes may be negative: '-3', '-5--2', '-2-1'. ``limit``: LfusdError, before any list is
    made, when the ranges name more frames than that."""
    ranges = []
    for part in str(text).split(","):
        m = re.fullmatch(r"\s*(-?\d+)\s*(?:-\s*(-?\d+)\s*)?", part)
        if not m:
            raise LfusdError(f"frames {text!r} is not N, A-B or a list of them such as 1-5,8 (negative time codes: -5--2)")
        a, b = int(m[1]), int(m[2] or m[1])
        if b < a:
            raise LfusdError(f"frames {text!r}: range {a}-{b} is reversed; write A-B with A <= B ({b}-{a})")
        ranges.append((a, b))
    count = sum(b - a + 1 for a, b in ranges)
    if limit is not None and count > limit:
        raise LfusdError(f"frames {text!r} name {count} frames, more than a dataset holds ({limit}); give a smaller range")
    frames: set[int] = set()
    for a, b in ranges:
        frames.update(range(a, b + 1))
    return sorted(frames)


def parse_view(text: str) -> View:
    """'4,4' or '4_4' -> (4, 4): a view's grid row and column."""
    m = re.fullmatch(r"\s*(\d+)\s*[,_]\s*(\d+)\s*", str(text))
    if not m:
        raise LfusdError(f"view {text!r} is not ROW,COL or ROW_COL (two integers, e.g. 4,4)")
    return int(m[1]), int(m[2])


# -- the pinhole camera model ---------------------------------------------------------------


@dataclass
class Camera:
    """Pinhole camera: OpenCV K (pixel centres at integer coordinates) and 4x4 OpenCV cam_to_world;
    with ``dist`` (lens distortion), pixel coordinates are distorted ones: :func:`project` images a
    point as cv2.projectPoints does, :func:`ray_directions` and :func:`backproject` take the ray the
    lens images at a pixel."""

    K: np.ndarray
    cam_to_world: np.ndarray
    dist: Distortion | None = None

    def _undistorted(self, u, v):
        """Pinhole pixel coordinates (of K) of pixel coordinates (u, v), in their float precision."""
        if self.dist is None or self.dist.is_identity:
            return u, v
        dt = _float_dtype(np.asarray(u))
        uu, vu = undistort_pixels(u, v, self.K, self.dist)
        return uu.astype(dt), vu.astype(dt)

    def world_to_cam(self) -> tuple[np.ndarray, np.ndarray]:
        """(R, C): camera-frame point = R @ (world point - C)."""
        m = np.asarray(self.cam_to_world, dtype=np.float64)
        return m[:3, :3].T, m[:3, 3]

    def _pixel_to_world(self, dtype) -> np.ndarray:
        """3x3 map of homogeneous pixel coordinates (u, v, 1) to world ray directions with camera-frame z = 1."""
        R, _ = self.world_to_cam()
        return (R.T @ np.linalg.inv(np.asarray(self.K, dtype=np.float64))).astype(dtype)


_GRIDS: dict[tuple[int, int, str], tuple[np.ndarray, np.ndarray]] = {}


def pixel_grid(h: int, w: int, dtype=np.float32) -> tuple[np.ndarray, np.ndarray]:
    """(u, v) pixel-centre coordinates, u = column, v = row (cached, read-only)."""
    key = (h, w, np.dtype(dtype).name)
    if key not in _GRIDS:
        v, u = np.mgrid[0:h, 0:w].astype(dtype)
        u.setflags(write=False)
        v.setflags(write=False)
        _GRIDS[key] = (u, v)
    return _GRIDS[key]


def _float_dtype(a: np.ndarray):
    return a.dtype if np.issubdtype(a.dtype, np.floating) else np.float64


def project(points: np.ndarray, cam: Camera) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(u, v, z) of world points (...,3) in ``cam``, in the points' float precision; z is planar depth (<= 0 behind the camera)."""
    points = np.asarray(points)
    dt = _float_dtype(points)
    R, C = cam.world_to_cam()
    K = np.asarray(cam.K, dtype=np.float64)
    # Subtract the centre before rotating so float32 keeps precision far from the world origin.
    d = points - C.astype(dt)
    M = (K @ R).astype(dt)
    x = d @ M.T
    z = d @ R[2].astype(dt)
    with np.errstate(divide="ignore", invalid="ignore"):
        u, v = x[..., 0] / x[..., 2], x[..., 1] / x[..., 2]
    if cam.dist is not None and not cam.dist.is_identity:
        u, v = (a.astype(dt) for a in distort_pixels(u, v, cam.K, cam.dist))
    return u, v, z


def ray_directions(u: np.ndarray, v: np.ndarray, cam: Camera) -> np.ndarray:
    """World directions (...,3) of the rays through pixel coordinates (u, v), scaled to camera-frame z = 1 (a ray parameter is then planar depth)."""
    u = np.asarray(u)
    A = cam._pixel_to_world(_float_dtype(u))
    u, v = cam._undistorted(u, v)
    return np.stack([u, v, np.ones_like(u)], axis=-1) @ A.T


def backproject(u: np.ndarray, v: np.ndarray, z: np.ndarray, cam: Camera) -> np.ndarray:
    """World points (...,3) at pixel coordinates (u, v) with planar depth z."""
    u = np.asarray(u)
    dt = _float_dtype(u)
    A = cam._pixel_to_world(dt)
    _, C = cam.world_to_cam()
    u, v = cam._undistorted(u, v)
    x = np.stack([u, v, np.ones_like(u)], axis=-1) * z[..., None]
    return x @ A.T + C.astype(dt)


def ray_lengths(K: np.ndarray, h: int, w: int, dist: Distortion | None = None) -> np.ndarray:
    """||K^-1 [u, v, 1]|| per pixel centre (float64, H x W), (u, v) undistorted through ``dist``: the ray length per metre of planar depth."""
    u, v = pixel_grid(h, w, np.float64)
    return np.linalg.norm(ray_directions(u, v, Camera(K, np.eye(4), dist)), axis=-1)


# -- lens distortion (Brown-Conrady, OpenCV's model) -----------------------------------------

DISTORTION_COEFFS = ("k1", "k2", "p1", "p2", "k3")  # OpenCV's order of distCoeffs
UNDISTORT_TOL = 1e-12  # Newton's stopping step in normalised coordinates (1e-9 px at f = 1000 px)
FOLD_TOL_PX = 1e-4  # a point the lens images where it projects undistorts back to it within this (Newton reaches 1e-9)


@dataclass(frozen=True)
class Distortion:
    """OpenCV's Brown-Conrady lens model (k1, k2, p1, p2, k3): a point at normalised pinhole
    coordinates (x, y) = (X/Z, Y/Z), r^2 = x^2 + y^2, is imaged at K @ (xd, yd, 1) with
    xd = x (1 + k1 r^2 + k2 r^4 + k3 r^6) + 2 p1 x y + p2 (r^2 + 2 x^2) and
    yd = y (1 + k1 r^2 + k2 r^4 + k3 r^6) + p1 (r^2 + 2 y^2) + 2 p2 x y (cv2.projectPoints)."""

    k1: float = 0.0
    k2: float = 0.0
    p1: float = 0.0
    p2: float = 0.0
    k3: float = 0.0

    def __post_init__(self) -> None:
        for name in DISTORTION_COEFFS:
            v = getattr(self, name)
            if not (isinstance(v, (int, float)) and math.isfinite(v)):
                raise LfusdError(f"lens distortion {name} must be a finite number, got {v!r}")

    @property
    def coeffs(self) -> np.ndarray:
        """OpenCV's distCoeffs (k1, k2, p1, p2, k3), float64."""
        return np.array([getattr(self, n) for n in DISTORTION_COEFFS], np.float64)

    @property
    def is_identity(self) -> bool:
        return not self.coeffs.any()

    def to_dict(self) -> dict:
        return {n: float(getattr(self, n)) for n in DISTORTION_COEFFS}

    @classmethod
    def from_dict(cls, d: dict) -> "Distortion":
        unknown = set(d) - set(DISTORTION_COEFFS)
        if unknown:
            raise LfusdError(f"lens distortion has unknown coefficient(s) {', '.join(sorted(unknown))}; use {', '.join(DISTORTION_COEFFS)}")
        return cls(**{k: float(v) for k, v in d.items()})

    # -- the model in normalised coordinates ---------------------------------------------
    def distort(self, x: np.ndarray, y: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Distorted normalised coordinates of undistorted normalised (x, y)."""
        k1, k2, p1, p2, k3 = self.coeffs
        r2 = x * x + y * y
        radial = 1.0 + r2 * (k1 + r2 * (k2 + r2 * k3))
        xy = x * y
        return x * radial + 2.0 * p1 * xy + p2 * (r2 + 2.0 * x * x), y * radial + p1 * (r2 + 2.0 * y * y) + 2.0 * p2 * xy

    def jacobian(self, x: np.ndarray, y: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """d(xd, yd)/d(x, y) as (dxd/dx, dxd/dy, dyd/dx, dyd/dy)."""
        k1, k2, p1, p2, k3 = self.coeffs
        r2 = x * x + y * y
        radial = 1.0 + r2 * (k1 + r2 * (k2 + r2 * k3))
        dradial = k1 + r2 * (2.0 * k2 + 3.0 * k3 * r2)  # d radial / d r2
        a = radial + 2.0 * x * x * dradial + 2.0 * p1 * y + 6.0 * p2 * x
        b = 2.0 * x * y * dradial + 2.0 * p1 * x + 2.0 * p2 * y
        c = 2.0 * x * y * dradial + 2.0 * p1 * x + 2.0 * p2 * y
        d = radial + 2.0 * y * y * dradial + 6.0 * p1 * y + 2.0 * p2 * x
        return a, b, c, d

    def undistort(self, xd: np.ndarray, yd: np.ndarray, iterations: int = 50) -> tuple[np.ndarray, np.ndarray]:
        """Undistorted normalised (x, y) of distorted (xd, yd), by Newton's method to float64 precision
        (OpenCV's undistortPoints stops after a few fixed-point steps); NaN where it does not converge."""
        xd, yd = np.asarray(xd, np.float64), np.asarray(yd, np.float64)
        x, y = xd.copy(), yd.copy()
        for _ in range(iterations):
            fx, fy = self.distort(x, y)
            ex, ey = fx - xd, fy - yd
            a, b, c, d = self.jacobian(x, y)
            det = a * d - b * c
            with np.errstate(divide="ignore", invalid="ignore"):
                sx, sy = (d * ex - b * ey) / det, (a * ey - c * ex) / det
            x, y = x - sx, y - sy
            if not np.nanmax(np.abs(np.concatenate([np.ravel(sx), np.ravel(sy), [0.0]]))) > UNDISTORT_TOL:
                break
        fx, fy = self.distort(x, y)
        bad = ~(np.abs(fx - xd) + np.abs(fy - yd) <= 1e-10)
        x, y = np.where(bad, np.nan, x), np.where(bad, np.nan, y)
        return x, y


def check_distortion(dist: Distortion, K: np.ndarray, width: int, height: int) -> None:
    """Refuse a model that is not one-to-one over the image: its Jacobian must stay positive (the
    image of every distorted pixel one ray) on a ray fan well past the image's corners."""
    if dist.is_identity:
        return
    Kinv = np.linalg.inv(np.asarray(K, np.float64))
    corners = np.array([[-0.5, -0.5, 1], [width - 0.5, -0.5, 1], [-0.5, height - 0.5, 1], [width - 0.5, height - 0.5, 1]]) @ Kinv.T
    x, y = dist.undistort(corners[:, 0], corners[:, 1])
    if not (np.isfinite(x).all() and np.isfinite(y).all()):
        raise LfusdError(f"lens distortion {dist.to_dict()} folds over the image (no ray reaches its corners); use smaller coefficients")
    r = 1.2 * float(np.hypot(x, y).max()) + 1e-6
    gx, gy = np.meshgrid(np.linspace(-r, r, 257), np.linspace(-r, r, 257))
    inside = np.hypot(gx, gy) <= r
    a, b, c, d = dist.jacobian(gx[inside], gy[inside])
    if (a * d - b * c).min() <= 0 or min(a.min(), d.min()) <= 0:
        raise LfusdError(f"lens distortion {dist.to_dict()} folds over the image (two rays meet at one pixel); use smaller coefficients")


def distort_pixels(u: np.ndarray, v: np.ndarray, K: np.ndarray, dist: Distortion) -> tuple[np.ndarray, np.ndarray]:
    """Distorted pixel coordinates of undistorted (pinhole) pixel coordinates of the same K."""
    K = np.asarray(K, np.float64)
    x, y = (np.asarray(u, np.float64) - K[0, 2]) / K[0, 0], (np.asarray(v, np.float64) - K[1, 2]) / K[1, 1]
    xd, yd = dist.distort(x, y)
    return xd * K[0, 0] + K[0, 2], yd * K[1, 1] + K[1, 2]


def undistort_pixels(u: np.ndarray, v: np.ndarray, K: np.ndarray, dist: Distortion) -> tuple[np.ndarray, np.ndarray]:
    """Undistorted (pinhole) pixel coordinates, in the same K, of distorted pixel coordinates."""
    K = np.asarray(K, np.float64)
    x, y = dist.undistort((np.asarray(u, np.float64) - K[0, 2]) / K[0, 0], (np.asarray(v, np.float64) - K[1, 2]) / K[1, 1])
    return x * K[0, 0] + K[0, 2], y * K[1, 1] + K[1, 2]


def project_distorted(points: np.ndarray, cam: Camera, dist: Distortion) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(u, v, z) of world points in ``cam`` through the lens ``dist`` (float64): cv2.projectPoints' pixels, planar depth z."""
    return project(np.asarray(points, np.float64), Camera(cam.K, cam.cam_to_world, dist))


def distorted_ray_directions(u: np.ndarray, v: np.ndarray, cam: Camera, dist: Distortion) -> np.ndarray:
    """World directions (...,3, float64, camera-frame z = 1) of the rays the lens images at distorted pixels (u, v)."""
    return ray_directions(np.asarray(u, np.float64), np.asarray(v, np.float64), Camera(cam.K, cam.cam_to_world, dist))


def wide_intrinsics(K: np.ndarray, dist: Distortion, width: int, height: int, margin: float = 2.0) -> tuple[np.ndarray, int, int]:
    """(K_wide, width_wide, height_wide): the pinhole with K's focal length whose image holds the
    undistorted rays of every distorted pixel's footprint (its border at +-1/2 px) with ``margin``
    pixels to spare for interpolation, grown by whole pixels on both sides (its principal point
    stays at its image centre, as Blender's camera has it, on K's pixel lattice)."""
    K = np.asarray(K, np.float64)
    n = 64
    us = np.concatenate([np.linspace(-0.5, width - 0.5, n), np.full(n, width - 0.5), np.linspace(-0.5, width - 0.5, n), np.full(n, -0.5)])
    vs = np.concatenate([np.full(n, -0.5), np.linspace(-0.5, height - 0.5, n), np.full(n, height - 0.5), np.linspace(-0.5, height - 0.5, n)])
    # the whole image, not only its border: a pincushion's undistorted extreme may lie inside
    gu, gv = np.meshgrid(np.linspace(-0.5, width - 0.5, n), np.linspace(-0.5, height - 0.5, n))
    uu, vu = undistort_pixels(np.concatenate([us, gu.ravel()]), np.concatenate([vs, gv.ravel()]), K, dist)
    if not (np.isfinite(uu).all() and np.isfinite(vu).all()):
        raise LfusdError(f"lens distortion {dist.to_dict()} folds over the image (no ray reaches its border); use smaller coefficients")
    cx, cy = K[0, 2], K[1, 2]
    pad_x = max(0, math.ceil(max(cx - uu.min(), uu.max() - cx) + margin - (width - 1) / 2.0))
    pad_y = max(0, math.ceil(max(cy - vu.min(), vu.max() - cy) + margin - (height - 1) / 2.0))
    Kw = K.copy()
    Kw[0, 2], Kw[1, 2] = cx + pad_x, cy + pad_y
    return Kw, width + 2 * pad_x, height + 2 * pad_y


def view_distortion(base: Distortion, view: View, seed: int | None = None, spread: float = 0.0) -> Distortion:
    """The lens of one view: ``base`` for every view, or with ``seed`` each coefficient scaled by
    (1 + spread * N(0, 1)) drawn for the view (real arrays' lenses differ), reproducible per (seed, view)."""
    if seed is None or spread == 0.0:
        return base
    rng = np.random.default_rng([int(seed), int(view[0]), int(view[1]), 0x1E45])
    scale = 1.0 + float(spread) * rng.standard_normal(len(DISTORTION_COEFFS))
    return Distortion(**{n: float(getattr(base, n) * s) for n, s in zip(DISTORTION_COEFFS, scale)})


def rig_distortions(spec: RigSpec, base: Distortion, seed: int | None = None, spread: float = 0.0) -> dict[View, Distortion]:
    """Every view's lens (:func:`view_distortion`), each checked one-to-one over the rig's image
    (:func:`check_distortion`: a model that folds is refused in one line, naming the view)."""
    K = spec.intrinsics()
    out = {}
    for view in spec.views:
        dist = view_distortion(base, view, seed, spread)
        try:
            check_distortion(dist, K, spec.width, spec.height)
        except LfusdError as e:
            where = f" (view {view[0]},{view[1]} of rig {spec.name}, drawn with --lens-seed {seed})" if dist != base else ""
            raise LfusdError(f"{e}{where}") from None
        out[view] = dist
    return out


def has_lens(cam: Camera) -> bool:
    """Whether ``cam`` images through a lens distortion (Camera.dist, not the identity)."""
    return cam.dist is not None and not cam.dist.is_identity


def project_imaged(points: np.ndarray, cam: Camera) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """(u, v, z, imaged) of world points (..., 3) in ``cam`` (float64): the distorted pixel coordinates
    (cv2.projectPoints'), planar depth, and whether the lens images the point there: in front of the
    camera and not beyond the model's fold (undistorting its pixel gives its own ray back)."""
    pts = np.asarray(points, np.float64)
    K = np.asarray(cam.K, np.float64)
    with np.errstate(invalid="ignore", divide="ignore"):
        uu, vu, z = project(pts, Camera(K, cam.cam_to_world))  # the pinhole of K
        if not has_lens(cam):
            return uu, vu, z, np.isfinite(uu) & np.isfinite(vu) & (z > 0)
        ud, vd = distort_pixels(uu, vu, K, cam.dist)
        ok = np.isfinite(ud) & np.isfinite(vd) & (z > 0)
        ub, vb = undistort_pixels(np.where(ok, ud, K[0, 2]), np.where(ok, vd, K[1, 2]), K, cam.dist)
        ok &= (np.abs(ub - uu) <= FOLD_TOL_PX) & (np.abs(vb - vu) <= FOLD_TOL_PX)
    return ud, vd, z, ok


def point_disparity(points: np.ndarray, cam: Camera, baseline: float) -> np.ndarray:
    """The disparity (docs/CONVENTIONS.md, "Lens distortion") of world points in ``cam``: u - u', u' the
    distorted column at which ``cam`` moved ``baseline`` along its own x axis (same K, same lens) images
    the point; f_px * b / z through a pinhole. NaN where either camera does not image it (behind, beyond the fold)."""
    u, _, _, ok = project_imaged(points, cam)
    shifted = np.array(cam.cam_to_world, np.float64)
    shifted[:3, 3] += float(baseline) * shifted[:3, 0]
    u1, _, _, ok1 = project_imaged(points, Camera(cam.K, shifted, cam.dist))
    return np.where(ok & ok1, u - u1, np.nan)

"""Lens distortion in Cycles: an OSL custom camera (Blender 5.0) that casts, for every sample on the
sensor, the ray the Brown-Conrady model (lfusd.camera.Distortion) images there.

Every pass Cycles writes through it (the image, position, normal, object index, the AOVs) is then in
distorted pixel coordinates with no resampling: the data render's one sample per pixel is the
distorted pixel centre's own ray, exactly as the pinhole's is. Cycles' depth pass of a custom camera
is the distance along the ray, not the planar depth (see :func:`planar_depth`).

The shader is generated per view with the view's coefficients and intrinsics as constants; it
undistorts the sensor position by Newton's method (as lfusd.camera.Distortion.undistort does, in the
shader's float precision). Its raster position runs 0..1 left to right and bottom to top; its camera
frame is x right, y up, z forward (checked by tests/render/test_lens_render.py).

With ``--fstop`` the beauty's shader is also a thin lens (Cycles ignores its own depth of field for a
custom camera): each sample leaves a point O of the aperture disc (the camera-frame plane z = 0,
radius ``aperture_radius``, sampled uniformly from camera_shader_random_sample()) towards the point
the pinhole ray of its undistorted (x, y) meets on the focus plane, P = (x, -y, 1) * focus (planar
depth, as Cycles' own thin lens focuses). A surface point at planar depth z then spreads over the
undistorted disc of radius aperture_radius * |1/focus - 1/z| about its own (x, y), which the lens
images through the model (lfusd.data.passes.circle_of_confusion). Blender honours a custom camera's
ray origin (measured with bpy 5.0.1: an origin at camera-frame (0.3, 0.2, 0) moves the position
pass by 0.3 m right and 0.2 m up). The data render's shader has no aperture: one ray through the
lens centre per pixel, as before.
"""

from __future__ import annotations

import numpy as np

from ..camera import Distortion, pixel_grid, undistort_pixels

NEWTON_STEPS = 12  # float32 Newton converges in a handful of steps for any model check_distortion accepts


def osl_source(dist: Distortion, K: np.ndarray, width: int, height: int, offset_px: tuple[float, float] = (0.0, 0.0),
               aperture_radius: float = 0.0, focus: float = 0.0) -> str:
    """OSL source of the custom camera of one view: pixel (u, v) (centres at integers, v down) of a
    sample -> the ray of its undistorted normalised coordinates. ``offset_px``: a sub-pixel shift of
    every sample (the data render's tie-breaking offset, lfusd.render.worker.SAMPLE_OFFSET_PX).
    ``aperture_radius`` > 0 (scene units, with ``focus`` > 0 the planar focus distance): a thin lens
    (the module's docstring); 0: every ray leaves the lens centre."""
    if aperture_radius < 0 or (aperture_radius > 0 and not focus > 0):
        raise ValueError(f"a thin lens needs an aperture radius >= 0 and a focus distance > 0, got {aperture_radius!r}, {focus!r}")
    K = np.asarray(K, np.float64)
    k1, k2, p1, p2, k3 = (repr(float(c)) for c in dist.coeffs)
    fx, fy, cx, cy = (repr(float(c)) for c in (K[0, 0], K[1, 1], K[0, 2], K[1, 2]))
    ou, ov = (repr(float(c)) for c in offset_px)
    return f"""// lfusd lens: Brown-Conrady (OpenCV) k1={k1} k2={k2} p1={p1} p2={p2} k3={k3}
shader lfusd_lens(output point position = 0, output vector direction = 0, output color throughput = 1)
{{
    point raster = camera_shader_raster_position();
    float pu = raster[0] * {width}.0 - 0.5 - {ou};
    float pv = (1.0 - raster[1]) * {height}.0 - 0.5 - {ov};
    float xd = (pu - {cx}) / {fx};
    float yd = (pv - {cy}) / {fy};
    float x = xd;
    float y = yd;
    for (int i = 0; i < {NEWTON_STEPS}; i++) {{
        float r2 = x * x + y * y;
        float radial = 1.0 + r2 * ({k1} + r2 * ({k2} + r2 * {k3}));
        float dradial = {k1} + r2 * (2.0 * {k2} + 3.0 * {k3} * r2);
        float ex = x * radial + 2.0 * {p1} * x * y + {p2} * (r2 + 2.0 * x * x) - xd;
        float ey = y * radial + {p1} * (r2 + 2.0 * y * y) + 2.0 * {p2} * x * y - yd;
        float a = radial + 2.0 * x * x * dradial + 2.0 * {p1} * y + 6.0 * {p2} * x;
        float b = 2.0 * x * y * dradial + 2.0 * {p1} * x + 2.0 * {p2} * y;
        float d = radial + 2.0 * y * y * dradial + 6.0 * {p1} * y + 2.0 * {p2} * x;
        float det = a * d - b * b;
        x -= (d * ex - b * ey) / det;
        y -= (a * ey - b * ex) / det;
    }}
{_ray(aperture_radius, focus)}
}}
"""


def _ray(aperture_radius: float, focus: float) -> str:
    """The shader's last lines: the ray of undistorted (x, y) (OpenCV axes), through the lens centre or a thin lens."""
    if aperture_radius == 0:
        return """    position = point(0, 0, 0);
    direction = normalize(vector(x, -y, 1.0));"""
    # Shirley's concentric map of the square's two uniform randoms onto the disc: uniform over the
    # disc and keeping the samples' stratification (Cycles' own aperture sampling does the same)
    return f"""    vector rnd = camera_shader_random_sample();
    float sa = 2.0 * rnd[0] - 1.0;
    float sb = 2.0 * rnd[1] - 1.0;
    float rho = 0.0;
    float phi = 0.0;
    if (sa * sa > sb * sb) {{
        rho = sa;
        phi = M_PI_4 * (sb / sa);
    }} else if (sb != 0.0) {{
        rho = sb;
        phi = M_PI_2 - M_PI_4 * (sa / sb);
    }}
    rho *= {float(aperture_radius)!r};
    position = point(rho * cos(phi), rho * sin(phi), 0.0);
    direction = normalize(vector(x, -y, 1.0) * {float(focus)!r} - vector(position));"""


def planar_depth(ray_distance: np.ndarray, dist: Distortion, K: np.ndarray) -> np.ndarray:
    """Planar depth (float32, H x W) from the depth pass of the custom camera (the distance along each
    distorted pixel's ray): the distance over ||(x, y, 1)||, (x, y) the pixel's undistorted normalised
    coordinates; no surface (Blender's background depth) stays inf-like."""
    h, w = ray_distance.shape
    u, v = pixel_grid(h, w, np.float64)
    K = np.asarray(K, np.float64)
    uu, vu = undistort_pixels(u, v, K, dist)
    length = np.sqrt(((uu - K[0, 2]) / K[0, 0]) ** 2 + ((vu - K[1, 2]) / K[1, 1]) ** 2 + 1.0)
    return (np.asarray(ray_distance, np.float64) / length).astype(np.float32)

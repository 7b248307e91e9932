"""Ground-truth accuracy of `lfusd render` against closed-form ray casts: `.venv/bin/python benchmarks/accuracy_static.py`.

Renders the box test scene (a 3x3 planar rig at 64x48 and a 2x3 spherical rig at 40x40) and
prints depth relative error, position-pass reprojection error and the disparity-shift error.
"""
import sys, tempfile
from pathlib import Path
sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests"))
import numpy as np
from support.analytic import cast, project
from support.scenes import PLANE_RIG, SPHERE_RIG, GROUND_HALF, boxes_world, write_box_stage
from lfusd import Dataset
from lfusd.render.job import RenderRequest, render
tmp = Path(tempfile.mkdtemp())
write_box_stage(tmp / "s.usda", [PLANE_RIG, SPHERE_RIG])
render(RenderRequest(stage=tmp / "s.usda", out=tmp / "o", rig="all", samples=4, device="cpu", quiet=True))
for rig in ("main", "dome"):
    ds = Dataset(tmp / "o", rig=rig); w, h = ds.resolution
    v, u = np.mgrid[0:h, 0:w]
    rel, rep = [], []
    ids = {o.prim_path: i for i, o in ds.objects.items()}
    for view in ds.views:
        d_ref, hit = cast(ds.intrinsics(view), ds.cam_to_world(1, view), w, h, boxes_world(), GROUND_HALF)
        ref_id = np.vectorize(lambda x: ids.get("/World/Ground" if x == "ground" else x, 0))(hit)
        inst, d, pos = ds.read(1, view, "instance"), ds.read(1, view, "depth"), ds.read(1, view, "position")
        same = (ref_id == inst) & (ref_id > 0)
        m = same.copy(); m[1:] &= same[:-1]; m[:-1] &= same[1:]; m[:, 1:] &= same[:, :-1]; m[:, :-1] &= same[:, 1:]
        rel.append(np.abs(d[m] - d_ref[m]) / d_ref[m])
        ok = np.isfinite(pos).all(-1)
        rep.append(np.hypot(*(project(ds.intrinsics(view), ds.cam_to_world(1, view), pos[ok]) - np.stack([u[ok], v[ok]], -1)).T))
    rel, rep = np.concatenate(rel), np.concatenate(rep)
    print(f"rig {rig} ({ds.rig.rows}x{ds.rig.cols}, {w}x{h}, {ds.rig.layout}): depth rel err median {np.median(rel):.1e} p99 {np.percentile(rel, 99):.1e} max {rel.max():.1e} ({rel.size} px); reprojection median {np.median(rep):.1e} px max {rep.max():.1e} px")
ds = Dataset(tmp / "o", rig="main"); c = ds.rig.centre_view; Tc = ds.cam_to_world(1, c); w, h = ds.resolution
v, u = np.mgrid[0:h, 0:w]; errs = []
for view in ds.views:
    sx, sy = ds.rig.offsets(view); pos = ds.read(1, view, "position"); ok = np.isfinite(pos).all(-1)
    uvc = project(ds.intrinsics(c), Tc, pos[ok]); zc = pos[ok] @ np.linalg.inv(Tc)[2, :3] + np.linalg.inv(Tc)[2, 3]
    d = ds.rig.focal_px * ds.baseline / zc
    errs.append(np.hypot(uvc[:, 0] - d * sx - u[ok], uvc[:, 1] - d * sy - v[ok]))
e = np.concatenate(errs); print(f"disparity shift between views: median {np.median(e):.1e} px, max {e.max():.1e} px")

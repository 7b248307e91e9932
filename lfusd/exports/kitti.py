"""KITTI 2015 scene-flow layout (``lfusd export kitti``), and reading it back for ``lfusd eval``.

Frame pairs (t, t+1) under ``training/``: the centre view is the left camera (``image_2``), its
right neighbour the right one (``image_3``); ``disp_occ_0`` (disparity at t), ``disp_occ_1``
(disparity at t+1 of the point seen at t), ``flow_occ`` (forward flow), and their ``noc`` versions
holding only points whose correspondences fall inside the other image(s) (:func:`kitti_noc`; which
points another view sees: :func:`lfusd.truth.visibility.visible_in_view`). Values are rounded to
1/256 px (disparity) and 1/64 px (flow), the format's precision.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from ..data import formats
from ..errors import LfusdError
from ..truth.visibility import inside_image
from .common import check_planar_grid, frames_of, new_dest
from .registry import Reader, register

def kitti_noc(d0, d1, flow, occ_0, occ_1) -> tuple[np.ndarray, np.ndarray]:
    """(noc_0, noc_1) as the KITTI 2015 devkit readme defines 'noc': the pixels of ``occ_0`` /
    ``occ_1`` whose matching correspondences fall inside the image domain. ``noc_0``: the right
    image's (u - d0, v); ``noc_1``: the left image at t+1, (u + du, v + dv), and the right one at
    t+1, (u + du - d1, v + dv). A correspondence that is occluded there still counts (the
    readme's 'occ' and 'noc' differ only by points leaving the image)."""
    h, w = np.shape(d0)
    v, u = np.mgrid[0:h, 0:w].astype(np.float64)
    d0, d1, flow = (np.asarray(a, np.float64) for a in (d0, d1, flow))
    noc_0 = np.asarray(occ_0, bool) & inside_image(u - d0, v, w, h)
    u1, v1 = u + flow[..., 0], v + flow[..., 1]
    noc_1 = np.asarray(occ_1, bool) & inside_image(u1, v1, w, h) & inside_image(u1 - d1, v1, w, h)
    return noc_0, noc_1


def kitti_masks(ds, t: int, left, right) -> dict[str, np.ndarray]:
    """The KITTI validity masks of frame pair (t, t+1): ``occ_0`` / ``noc_0`` (disparity at t:
    known / its right-image correspondence inside the image), ``occ_fwd`` / ``noc_fwd`` (flow: known
    / also visible in the left image at t+1), ``occ_1`` / ``noc_1`` (disparity at t+1: known / its
    correspondences at t+1 inside both images; :func:`kitti_noc`)."""
    d0 = np.asarray(ds.read(t, left, "disparity"), np.float64)
    occ_0 = np.isfinite(d0) & (d0 > 0) & np.isfinite(ds.read(t, left, "depth"))
    occ_fwd = np.asarray(ds.read(t, left, "valid_fwd"), bool) & occ_0
    noc_fwd = occ_fwd & ~np.asarray(ds.read(t, left, "occlusion_fwd"), bool)
    flow = np.asarray(ds.read(t, left, "flow_fwd"), np.float64)
    d1 = d0 + ds.read(t, left, "disparity_change")
    with np.errstate(invalid="ignore"):
        occ_1 = occ_fwd & np.isfinite(d1) & (d1 > 0)
    noc_0, noc_1 = kitti_noc(d0, d1, flow, occ_0, occ_1)
    return {"occ_0": occ_0, "noc_0": noc_0, "occ_fwd": occ_fwd, "noc_fwd": noc_fwd, "occ_1": occ_1, "noc_1": noc_1}


MOVING_M = 1e-5  # m per frame: above the stored scene flow's rounding (2^-18 m), far below any motion


def kitti_object_map(ds, t: int, view) -> np.ndarray:
    """KITTI's ``obj_map`` of frame pair (t, t+1) in ``view``: uint8, 0 = background, k > 0 the
    k-th object that moves between t and t+1 (capped at 255), the devkit's foreground
    (``evaluate_scene_flow.cpp``: ``O_map`` 0 background, > 0 foreground). An object moves when its
    world pose changes or a pixel of it has scene flow above :data:`MOVING_M` (a skinned body
    moves under a fixed pose)."""
    inst = np.asarray(ds.read(t, view, "instance"))
    moving = set()
    for oid, obj in ds.objects.items():
        poses = getattr(obj, "poses", {})
        if t in poses and t + 1 in poses and np.max(np.abs(np.asarray(poses[t + 1]) - np.asarray(poses[t]))) > MOVING_M:
            moving.add(int(oid))
    sf = np.asarray(ds.read(t, view, "scene_flow"), np.float64)
    ok = np.asarray(ds.read(t, view, "valid_fwd"), bool) & np.all(np.isfinite(sf), axis=-1)
    moving |= {int(i) for i in np.unique(inst[ok & (np.linalg.norm(np.where(ok[..., None], sf, 0.0), axis=-1) > MOVING_M)])}
    moving.discard(0)
    out = np.zeros(inst.shape, np.uint8)
    for k, oid in enumerate(sorted(moving), start=1):
        out[inst == oid] = min(k, 255)
    return out


# ---- reading an export back (lfusd eval --gt DEST --protocol kitti) ------------------------------


def kitti_root(path) -> Path | None:
    """The folder holding flow_occ/ or disp_occ_0/ when ``path`` is a KITTI export (DEST or DEST/training)."""
    p = Path(path)
    for q in (p, p / "training"):
        if (q / "flow_occ").is_dir() or (q / "disp_occ_0").is_dir():
            return q
    return None


def kitti_names(root: Path, task: str) -> list[str]:
    """The images of a KITTI folder with ``task`` ground truth: ``000000_10.png``, ..."""
    gt_dir = root / ("disp_occ_0" if task == "disparity" else "flow_occ")
    return sorted(p.name for p in gt_dir.glob("*_10.png"))


def kitti_truth(root: Path, name: str, task: str) -> dict:
    """Ground truth of image ``name`` (``000000_10.png``) of a KITTI folder, as the devkit reads it."""
    t: dict = {"kitti": True}

    def disp(sub):
        d, ok = formats.read_kitti_disparity(root / sub / name)
        return d.astype(np.float64), ok

    if task in ("flow", "sceneflow"):
        f, occ = formats.read_kitti_flow(root / "flow_occ" / name)
        _, noc = formats.read_kitti_flow(root / "flow_noc" / name)
        t |= {"flow": f.astype(np.float64), "flow_occ": occ, "flow_noc": noc}
    if task in ("disparity", "sceneflow"):
        t["disp0"], t["disp0_occ"] = disp("disp_occ_0")
        t["disp0_noc"] = disp("disp_noc_0")[1]
    if task == "sceneflow":
        t["disp1"], t["disp1_occ"] = disp("disp_occ_1")
        t["disp1_noc"] = disp("disp_noc_1")[1]
    if (root / "obj_map" / name).is_file():  # the devkit's bg / fg split
        t["obj_map"] = formats.read_png(root / "obj_map" / name)
    return t


@register("kitti", "KITTI 2015 scene-flow layout of frame pairs (centre view and its right neighbour)",
          reader=Reader(find=kitti_root, names=kitti_names, truth=kitti_truth, protocol="kitti",
                        predictions={"disparity": "disp_0", "flow": "flow", "sceneflow": "flow"}), pinhole=True)
def export_kitti(ds, dest, frame: int | None = None) -> Path:
    """Write frame pairs (t, t+1) in the KITTI 2015 scene-flow layout; returns ``dest/training``."""
    check_planar_grid(ds, "the KITTI layout")
    if ds.rig.cols < 2:
        raise LfusdError("the KITTI layout needs a right neighbour of the centre view; render a grid with at least 2 columns")
    rc, cc = ds.rig.centre_view
    left, right = (rc, cc), (rc, cc + 1)
    frames = [t for t in frames_of(ds, frame) if t + 1 in ds.frames]
    if not frames:
        raise LfusdError("KITTI pairs need frame t and t+1; pick a frame that has a next frame")
    dest = new_dest(dest)
    tr = dest / "training"
    for sub in ("image_2", "image_3", "disp_occ_0", "disp_noc_0", "disp_occ_1", "disp_noc_1", "flow_occ", "flow_noc", "obj_map"):
        (tr / sub).mkdir(parents=True)
    for i, t in enumerate(frames):
        name = f"{i:06d}_10.png"
        for sub, view in (("image_2", left), ("image_3", right)):
            formats.write_png(tr / sub / name, ds.read(t, view, "rgb"))
            formats.write_png(tr / sub / f"{i:06d}_11.png", ds.read(t + 1, view, "rgb"))
        m = kitti_masks(ds, t, left, right)
        d0 = ds.read(t, left, "disparity")
        d1 = d0 + ds.read(t, left, "disparity_change")
        flow = ds.read(t, left, "flow_fwd")
        formats.write_kitti_disparity(tr / "disp_occ_0" / name, d0, m["occ_0"])
        formats.write_kitti_disparity(tr / "disp_noc_0" / name, d0, m["noc_0"])
        formats.write_kitti_disparity(tr / "disp_occ_1" / name, d1, m["occ_1"])
        formats.write_kitti_disparity(tr / "disp_noc_1" / name, d1, m["noc_1"])
        formats.write_kitti_flow(tr / "flow_occ" / name, flow, m["occ_fwd"])
        formats.write_kitti_flow(tr / "flow_noc" / name, flow, m["noc_fwd"])
        formats.write_png(tr / "obj_map" / name, kitti_object_map(ds, t, left))
    (dest / "frames.txt").write_text("".join(f"{i:06d} frame {t} -> {t + 1}\n" for i, t in enumerate(frames)))
    return tr

"""Spring benchmark layout (``lfusd export spring``): ``train/<scene>/frame_left|right``, ``disp1_*``,
``disp2_FW_*``, ``flow_FW_*`` / ``flow_BW_*`` as .dsp5 / .flo5 at twice the image resolution
(Spring's loaders take every second sample)."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from ..data import formats
from ..errors import LfusdError
from .common import check_planar_grid, frames_of, new_dest, scene_name
from .registry import register

def _spring_path(sd: Path, kind: str, cam: str, i: int, ext: str) -> Path:
    """``sd/<kind>_<cam>/<kind>_<cam>_<i:04d>.<ext>`` (Spring's naming), creating the folder."""
    folder = sd / f"{kind}_{cam}"
    folder.mkdir(parents=True, exist_ok=True)
    return folder / f"{kind}_{cam}_{i:04d}.{ext}"


def spring_disparity(disparity) -> np.ndarray:
    """Disparity as the Spring layout stores it: NaN where there is no surface (lfusd's 0 for the
    sky, which Spring leaves without ground truth). ``lfusd eval --protocol spring`` scores the same
    pixels, so the official code on an export and ``lfusd eval`` on the dataset agree."""
    d = np.asarray(disparity, np.float32)
    with np.errstate(invalid="ignore"):
        return np.where(np.isfinite(d) & (d > 0), d, np.float32(np.nan))


def _spring_gt(a: np.ndarray) -> np.ndarray:
    """Spring's ground truth has twice the image resolution per axis and its loaders take
    ``gt[::2, ::2]``: each pixel's value fills its 2x2 block (lfusd's GT is at pixel centres)."""
    return np.repeat(np.repeat(a, 2, axis=0), 2, axis=1)


@register("spring", "Spring benchmark layout of consecutive frames (.dsp5 / .flo5)", pinhole=True)
def export_spring(ds, dest, frame: int | None = None) -> Path:
    """Write consecutive frames in the Spring layout; returns ``dest/train/<scene>``.

    The centre view is Spring's left camera, its right neighbour the right one; frames are
    renumbered 1, 2, ... (``frames.txt`` maps them). Per camera: ``disp1`` (disparity, positive:
    Spring's loader negates the left camera's), ``disp2_FW`` (disparity at t+1 of the point seen at
    t), ``flow_FW`` / ``flow_BW``; NaN where unknown. lfusd has no backward disparity change, so
    there is no ``disp2_BW``.
    """
    check_planar_grid(ds, "the Spring layout")
    if ds.rig.cols < 2:
        raise LfusdError("the Spring layout needs a right neighbour of the centre view; render a grid with at least 2 columns")
    frames = frames_of(ds, frame)
    if frames != list(range(frames[0], frames[0] + len(frames))):
        raise LfusdError(f"the Spring layout needs consecutive frames, this dataset has {frames}; finish the render or pick one --frame")
    rc, cc = ds.rig.centre_view
    cams = {"left": (rc, cc), "right": (rc, cc + 1)}
    dest = new_dest(dest)
    sd = dest / "train" / scene_name(ds)
    for i, t in enumerate(frames, start=1):
        for cam, view in cams.items():
            def out(kind: str, ext: str, cam=cam, i=i) -> Path:
                return _spring_path(sd, kind, cam, i, ext)

            formats.write_png(out("frame", "png"), ds.read(t, view, "rgb"))
            d = spring_disparity(ds.read(t, view, "disparity"))
            known = np.isfinite(d)
            formats.write_dsp5(out("disp1", "dsp5"), _spring_gt(d))
            for key, step, kind in (("fwd", 1, "FW"), ("bwd", -1, "BW")):
                if t + step not in frames:
                    continue
                flow = np.asarray(ds.read(t, view, f"flow_{key}"), np.float32)
                ok = np.asarray(ds.read(t, view, f"valid_{key}"), bool) & np.all(np.isfinite(flow), axis=-1)
                formats.write_flo5(out(f"flow_{kind}", "flo5"), _spring_gt(np.where(ok[..., None], flow, np.nan)))
                if key == "fwd":
                    d2 = d + np.asarray(ds.read(t, view, "disparity_change"), np.float32)
                    formats.write_dsp5(out("disp2_FW", "dsp5"), _spring_gt(np.where(ok & known, d2, np.nan)))
    (dest / "frames.txt").write_text("".join(f"{i:04d} frame {t}\n" for i, t in enumerate(frames, start=1)))
    return sd

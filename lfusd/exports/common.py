"""What every export format shares: file stems, scene names, the new target folder and the checks
of the frames, views and rig asked for."""

from __future__ import annotations

from pathlib import Path

from ..data import formats
from ..errors import LfusdError


def stem(frame: int, view) -> str:
    """The file stem of one frame and view: ``0001_04_04``."""
    return f"{int(frame):04d}_{int(view[0]):02d}_{int(view[1]):02d}"


def scene_name(ds) -> str:
    """The scene's name: the dataset folder's."""
    return Path(getattr(ds, "root", "scene")).name or "scene"


def new_dest(dest) -> Path:
    """Create the export target ``dest``, or LfusdError when it exists or cannot be made."""
    dest = Path(dest)
    if dest.exists():
        raise LfusdError(f"export target {dest} already exists; choose a new folder or remove it first")
    try:
        dest.mkdir(parents=True)
    except OSError as e:
        raise LfusdError(f"cannot create export target {dest} ({e.strerror}): {formats.why_unwritable(dest)}") from None
    return dest


def frames_of(ds, frame) -> list[int]:
    """The frames to export: ``frame``, or every complete frame when it is None."""
    if not ds.frames:
        raise LfusdError(f"dataset {getattr(ds, 'root', '')} has no completely rendered frame yet; finish its render first")
    if frame is None:
        return list(ds.frames)
    if frame not in ds.frames:
        raise LfusdError(f"frame {frame} is not in the dataset (it has frames {ds.frames[0]}..{ds.frames[-1]}); pick one of those")
    return [frame]


def view_of(ds, view):
    """``view`` as a (row, col) of the grid, or the centre view when it is None."""
    if view is None:
        return tuple(ds.rig.centre_view)
    view = tuple(int(v) for v in view)
    if view not in [tuple(v) for v in ds.views]:
        raise LfusdError(f"view {view} is not in the dataset's {ds.rig.rows}x{ds.rig.cols} grid; give row,col inside it")
    return view


def check_planar_grid(ds, what: str) -> None:
    """LfusdError unless the rig is a uniform planar parallel grid (one disparity for the grid)."""
    rig = ds.rig
    if getattr(rig, "layout", "plane") != "plane" or getattr(rig, "axes", "parallel") != "parallel" or getattr(rig, "spacing", "uniform") != "uniform":
        raise LfusdError(f"{what} needs a uniform planar parallel rig (one disparity for the grid); this dataset's rig is {rig.spacing}/{rig.layout}/{rig.axes}")


def views_for(ds, view, all_views):
    """Every view with ``all_views``, else the one :func:`view_of` gives."""
    return [tuple(v) for v in ds.views] if all_views else [view_of(ds, view)]

"""Opening stages with clear errors, and their frame range."""

from __future__ import annotations

import hashlib
from pathlib import Path

from pxr import Sdf, Tf, Usd, UsdGeom

from .errors import LfusdError


def open_stage(path: str | Path) -> Usd.Stage:
    """Open a USD stage, or raise LfusdError naming the file and what is wrong with it."""
    p = Path(path)
    if not p.exists():
        raise LfusdError(f"stage {p} does not exist; give the path of a .usda/.usdc/.usd file")
    if p.is_dir():
        raise LfusdError(f"stage {p} is a folder; give the path of a .usda/.usdc/.usd file")
    try:
        stage = Usd.Stage.Open(str(p))
    except Tf.ErrorException as e:
        first = str(e).strip().splitlines()
        reason = next((ln.strip() for ln in first if ln.strip().startswith(("Error", "Failed", "syntax", "unexpected"))), "")
        raise LfusdError(f"stage {p} is not a readable USD file ({reason or 'parse error'}); fix or regenerate it") from None
    if stage is None:
        raise LfusdError(f"stage {p} is not a readable USD file; fix or regenerate it")
    return stage


def frame_range(stage: Usd.Stage) -> tuple[int, int]:
    """(first, last) frame, inclusive; a stage with no authored time range is one static frame, 1."""
    if not stage.HasAuthoredTimeCodeRange():
        return 1, 1
    return int(round(stage.GetStartTimeCode())), int(round(stage.GetEndTimeCode()))


def check_frames(stage: Usd.Stage, frames: list[int], stage_path: str | Path) -> None:
    """Raise LfusdError when any frame lies outside the stage's range."""
    first, last = frame_range(stage)
    bad = [f for f in frames if not first <= f <= last]
    if bad:
        raise LfusdError(
            f"frame {bad[0]} is outside stage {stage_path}'s range {first}-{last}; pick frames in {first}-{last}"
        )


def file_hash(path: str | Path) -> str:
    """sha256 of the stage's root layer file (what the dataset was rendered from)."""
    h = hashlib.sha256()
    with open(path, "rb") as f:
        for chunk in iter(lambda: f.read(1 << 20), b""):
            h.update(chunk)
    return h.hexdigest()


def new_stage(path: str | Path, first: int = 1, last: int = 1) -> Usd.Stage:
    """A new stage with the project's conventions: metres, Z up, 24 time codes per second."""
    stage = Usd.Stage.CreateNew(str(path)) if path else Usd.Stage.CreateInMemory()
    UsdGeom.SetStageUpAxis(stage, UsdGeom.Tokens.z)
    UsdGeom.SetStageMetersPerUnit(stage, 1.0)
    stage.SetTimeCodesPerSecond(24)
    stage.SetFramesPerSecond(24)
    stage.SetStartTimeCode(first)
    stage.SetEndTimeCode(last)
    world = UsdGeom.Xform.Define(stage, Sdf.Path("/World"))
    stage.SetDefaultPrim(world.GetPrim())
    return stage


def meters_per_unit(stage: Usd.Stage) -> float:
    return float(UsdGeom.GetStageMetersPerUnit(stage))

"""File and folder naming of a dataset: the one place that says where each file lives."""

from __future__ import annotations

from pathlib import Path

FORMAT = "lfusd-dataset"
FORMAT_VERSION = 1


def view_key(view: tuple[int, int]) -> str:
    return f"{view[0]:02d}_{view[1]:02d}"


def frame_dir(root: Path, rig: str, frame: int) -> Path:
    return root / rig / f"f{frame:06d}"

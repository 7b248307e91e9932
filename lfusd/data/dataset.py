"""`Dataset`: read an lfusd dataset folder as NumPy arrays in the conventions of CONVENTIONS.md."""

from __future__ import annotations

import json
from dataclasses import dataclass, field
from functools import lru_cache
from pathlib import Path

import numpy as np

from . import passes
from ..errors import LfusdError
from ..render.job import FORMAT, frame_dir, view_key
from ..camera import RigSpec, View

# Keys derived from the data passes; motion keys come from the flow module's files.
RAW_KEYS = ("depth", "normal", "position", "instance", "vector", "next_position", "prev_position")
DERIVED_KEYS = ("semantic", "disparity")
IMAGE_KEYS = ("rgb", "rgb_linear")
MOTION_FILE = "motion.npz"


@dataclass
class DatasetObject:
    """One instance: its id, USD prim path, class label and world pose per frame."""

    instance_id: int
    prim_path: str
    label: str
    class_id: int
    poses: dict[int, np.ndarray] = field(default_factory=dict, repr=False)


class Dataset:
    """A rendered light-field dataset: ``Dataset(OUT)``, or ``Dataset(OUT, rig=NAME)`` when it holds several rigs."""

    def __init__(self, root: str | Path, rig: str | None = None):
        self.root = Path(root)
        path = self.root / "manifest.json"
        if not path.is_file():
            raise LfusdError(f"{self.root} holds no lfusd dataset (no manifest.json); render one with 'lfusd render'")
        self.manifest = json.loads(path.read_text())
        if self.manifest.get("format") != FORMAT:
            raise LfusdError(f"{path} is not an lfusd dataset manifest")
        rigs = self.manifest["rigs"]
        if rig is None:
            if len(rigs) != 1:
                raise LfusdError(f"{self.root} holds rigs {', '.join(rigs)}; open one with Dataset(path, rig=NAME)")
            rig = rigs[0]
        if rig not in rigs:
            raise LfusdError(f"{self.root} has no rig {rig!r}; it has {', '.join(rigs)}")
        self.rig: RigSpec = RigSpec.from_dict(self.manifest["settings"]["rigs"][rig])
        self.rig_name = rig
        table = json.loads((self.root / "objects.json").read_text())
        self.classes: list[str] = table["classes"]
        self._class_of_instance = np.zeros(max([o["id"] for o in table["objects"]], default=0) + 1, dtype=np.int32)
        for o in table["objects"]:
            self._class_of_instance[o["id"]] = o["class_id"]
        self._object_rows = table["objects"]
        self._objects: dict[int, DatasetObject] | None = None

    # -- structure --------------------------------------------------------------------
    @property
    def frames(self) -> list[int]:
        """Frames with every view rendered."""
        return [f for f in self.manifest["frames"] if all((self._frame_dir(f) / view_key(v)).is_dir() for v in self.views)]

    @property
    def views(self) -> list[View]:
        return self.rig.views

    @property
    def baseline(self) -> float:
        return float(self.rig.baseline)

    @property
    def resolution(self) -> tuple[int, int]:
        """(width, height) in pixels."""
        return self.rig.width, self.rig.height

    def intrinsics(self, view: View) -> np.ndarray:
        """3x3 OpenCV K (the same for every view of a rig)."""
        self._check_view(view)
        return self.rig.intrinsics()

    def cam_to_world(self, frame: int, view: View) -> np.ndarray:
        """4x4 OpenCV camera-to-world pose of ``view`` at ``frame`` (metres)."""
        self._check_view(view)
        return np.array(self._frame_meta(frame)["cam_to_world"][view_key(view)], dtype=np.float64)

    @property
    def objects(self) -> dict[int, DatasetObject]:
        if self._objects is None:
            objs = {o["id"]: DatasetObject(o["id"], o["prim_path"], o["label"], o["class_id"]) for o in self._object_rows}
            for f in self.frames:
                poses = self._frame_meta(f)["object_poses"]
                for o in objs.values():
                    o.poses[f] = np.array(poses[o.prim_path], dtype=np.float64)
            self._objects = objs
        return self._objects

    # -- pixels -------------------------------------------------------------------------
    def view_dir(self, frame: int, view: View) -> Path:
        self._check_view(view)
        d = self._frame_dir(frame) / view_key(view)
        if not d.is_dir():
            raise LfusdError(f"view {view} of frame {frame} is not rendered in {self.root}; rerun the render to complete it")
        return d

    def read(self, frame: int, view: View, key: str) -> np.ndarray:
        """One ground-truth array (see CONVENTIONS.md for keys, shapes and meanings)."""
        d = self.view_dir(frame, view)
        if key == "rgb":
            from .formats import read_png

            return read_png(d / "rgb.png")
        if key == "rgb_linear":
            return passes.read_rgb_linear(d / "rgb.exr")
        if key in RAW_KEYS:
            raw = self._raw(str(d))
            if key not in raw:
                raise LfusdError(f"{d / 'passes.exr'} has no {key} pass; render the dataset with 'lfusd render-video'")
            return raw[key].copy()  # the cache must not be mutated by callers
        if key == "semantic":
            return passes.semantic(self._raw(str(d))["instance"], self._class_of_instance)
        if key == "disparity":
            return passes.disparity(self._raw(str(d))["depth"], self.rig.focal_px, self.baseline)
        motion = d / MOTION_FILE
        if motion.is_file():
            with np.load(motion) as z:
                if key in z.files:
                    return z[key]
            raise LfusdError(f"unknown key {key!r}; {motion} holds {', '.join(sorted(z.files))}")
        known = IMAGE_KEYS + RAW_KEYS + DERIVED_KEYS
        raise LfusdError(f"unknown or missing key {key!r} for {d}; keys: {', '.join(known)} (motion keys need 'lfusd render-video')")

    def raw_passes(self, frame: int, view: View):
        """The view's raw passes with its camera, as lfusd.truth.motion.RawPasses (input of derive_motion)."""
        from ..truth.motion import Camera, RawPasses

        raw = self._raw(str(self.view_dir(frame, view)))
        if "vector" not in raw:
            raise LfusdError(f"{self.view_dir(frame, view) / 'passes.exr'} has no vector pass; re-render with 'lfusd render-video'")
        return RawPasses(
            depth=raw["depth"], vector=raw["vector"], camera=Camera(self.intrinsics(view), self.cam_to_world(frame, view)),
            position=raw["position"], instance=raw["instance"],
            next_position=raw.get("next_position"), prev_position=raw.get("prev_position"),
        )

    # -- internals ----------------------------------------------------------------------
    def _check_view(self, view: View) -> None:
        if tuple(view) not in set(self.views):
            raise LfusdError(f"view {view} is not in this {self.rig.rows}x{self.rig.cols} rig; rows 0-{self.rig.rows - 1}, cols 0-{self.rig.cols - 1}")

    def _frame_dir(self, frame: int) -> Path:
        return frame_dir(self.root, self.rig_name, frame)

    def _frame_meta(self, frame: int) -> dict:
        return _read_json(str(self._frame_dir(frame) / "frame.json"))

    @staticmethod
    @lru_cache(maxsize=4)
    def _raw(view_dir: str) -> dict[str, np.ndarray]:
        return passes.read_raw(Path(view_dir) / "passes.exr")


@lru_cache(maxsize=64)
def _read_json(path: str) -> dict:
    p = Path(path)
    if not p.is_file():
        raise LfusdError(f"{p} is missing; rerun the render to complete this frame")
    return json.loads(p.read_text())

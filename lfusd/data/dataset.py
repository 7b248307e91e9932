"""`Dataset`: read an lfusd dataset folder as NumPy arrays in the conventions of docs/CONVENTIONS.md.

Imports neither pxr, bpy nor torch: ``from lfusd import Dataset`` stays light.
"""

from __future__ import annotations

import json
import zipfile
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from . import passes
from .. import layout
from .integrity import complete_frames
from ..camera import RigSpec, View
from ..errors import LfusdError
from ..keys import IMAGE, RAW, STATIC, get
from ..layout import FORMAT, frame_dir, view_key


@dataclass
class DatasetObject:
    """One instance: its id, USD prim path, class label and world pose per frame."""

    instance_id: int
    prim_path: str
    label: str
    class_id: int
    poses: dict[int, np.ndarray] = field(default_factory=dict, repr=False)


class Dataset:
    """A rendered light-field dataset: ``Dataset(OUT)``, or ``Dataset(OUT, rig=NAME)`` when it holds several rigs.

    The manifest, the object table and the list of complete frames are read once, when the
    dataset is opened; :meth:`refresh` reads them again (for a dataset that is still rendering).
    """

    def __init__(self, root: str | Path, rig: str | None = None):
        self.root = Path(root)
        self._rig_arg = rig
        self.refresh(scan=False)

    def refresh(self, scan: bool = True) -> None:
        """Read the manifest and object table again and drop every cached array.

        ``scan``: find the complete frames by listing the view folders rather than trusting the
        manifest's record (which a render updates only when it ends).
        """
        path = self.root / layout.MANIFEST
        if not path.is_file():
            raise LfusdError(f"{self.root} holds no lfusd dataset (no {layout.MANIFEST}); render one with 'lfusd render'")
        self.manifest = _read_json(path, "rerun the render that made the dataset (it rewrites the manifest)")
        if not isinstance(self.manifest, dict) or self.manifest.get("format") != FORMAT:
            raise LfusdError(f"{path} is not an lfusd dataset manifest; open the output folder of 'lfusd render'")
        try:
            rigs = list(self.manifest["rigs"])
            rig_specs = self.manifest["settings"]["rigs"]
        except (KeyError, TypeError):
            raise LfusdError(f"{path} lacks its rigs record; rerun the render that made the dataset") from None
        rig = self._rig_arg
        if rig is None:
            if len(rigs) != 1:
                raise LfusdError(f"{self.root} holds rigs {', '.join(rigs)}; open one with Dataset(path, rig=NAME)")
            rig = rigs[0]
        if rig not in rigs:
            raise LfusdError(f"{self.root} has no rig {rig!r}; it has {', '.join(rigs)}")
        try:
            self.rig: RigSpec = RigSpec.from_dict(rig_specs[rig])
        except (KeyError, TypeError, ValueError):
            raise LfusdError(f"{path} holds no readable record of rig {rig!r}; rerun the render that made the dataset") from None
        self.rig_name = rig
        objects_path = self.root / layout.OBJECTS
        table = _read_json(objects_path, "rerun the render that made the dataset (it rewrites the object table)")
        try:
            self.classes: list[str] = list(table["classes"])
            self._class_of_instance = np.zeros(max([int(o["id"]) for o in table["objects"]], default=0) + 1, dtype=np.int32)
            for o in table["objects"]:
                self._class_of_instance[o["id"]] = o["class_id"]
        except (KeyError, TypeError, ValueError, IndexError):
            raise LfusdError(f"{objects_path} is not an lfusd object table; rerun the render that made the dataset") from None
        self._object_rows = table["objects"]
        self._objects: dict[int, DatasetObject] | None = None
        complete = self.manifest.get("complete", {}).get(rig)
        if scan or complete is None:  # manifests before the "complete" record: look at the folders
            # Sizes against each view's completion record (checksums: `lfusd verify --integrity`).
            complete = complete_frames(self.root, rig, self.manifest["frames"], self.views)
        self.frames: list[int] = [int(f) for f in complete]  # frames with every view rendered
        # Per-instance caches, most recent last: raw passes (t-1, t, t+1 of a view for the motion derivation), frame.json files.
        self._raw_cache: dict[str, dict[str, np.ndarray]] = {}
        self._meta_cache: dict[int, dict] = {}

    # -- structure --------------------------------------------------------------------
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
        """Instances by id, with their poses in every complete frame (read on first use, then kept)."""
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
        """One ground-truth array (lfusd.keys and docs/CONVENTIONS.md list the keys, shapes and meanings)."""
        k = get(key)
        d = self.view_dir(frame, view)
        if k.stage == IMAGE:
            if key == "rgb":
                from .formats import read_png

                return read_png(d / layout.RGB_PNG)
            return passes.read_rgb_linear(d / layout.RGB_EXR)
        if k.stage == RAW:
            raw = self._raw(str(d))
            if key not in raw:
                raise LfusdError(f"{d / layout.PASSES_EXR} has no {key} pass; render the dataset with 'lfusd render-video'")
            return raw[key].copy()  # the cache must not be mutated by callers
        if k.stage == STATIC:
            info = passes.ViewInfo(self.intrinsics(view), self.baseline, self._class_of_instance)
            return passes.DERIVED[key](self._raw(str(d)), info)
        motion = d / layout.MOTION_FILE
        if not motion.is_file():
            raise LfusdError(f"{d} has no {layout.MOTION_FILE} for key {key!r}; derive the motion keys with 'lfusd flow' (or render with 'lfusd render-video')")
        try:
            with np.load(motion) as z:
                if key not in z.files:
                    raise LfusdError(f"{motion} holds no {key!r} ({', '.join(sorted(z.files))}); derive it again with 'lfusd flow'")
                return z[key]
        except (OSError, ValueError, EOFError, zipfile.BadZipFile) as e:
            raise LfusdError(f"{motion} is unreadable ({e}); derive it again with 'lfusd flow'") from None

    def raw_passes(self, frame: int, view: View):
        """The view's raw passes with its camera (the input of lfusd.truth.motion.derive_motion)."""
        from ..camera import Camera
        from .passes import RawPasses

        raw = self._raw(str(self.view_dir(frame, view)))
        if "vector" not in raw:
            raise LfusdError(f"{self.view_dir(frame, view) / layout.PASSES_EXR} has no vector pass; re-render with 'lfusd render-video'")
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
        def load():
            p = self._frame_dir(frame) / layout.FRAME_META
            if not p.is_file():
                raise LfusdError(f"{p} is missing; rerun the render to complete this frame")
            return _read_json(p, "delete it and rerun the render to write it again")

        return _cached(self._meta_cache, frame, 64, load)

    def _raw(self, view_dir: str) -> dict[str, np.ndarray]:
        return _cached(self._raw_cache, view_dir, 4, lambda: passes.read_raw(Path(view_dir) / layout.PASSES_EXR))


def _read_json(path: Path, fix: str):
    """The JSON in ``path``, or LfusdError naming the file and ``fix``."""
    try:
        return json.loads(path.read_text())
    except FileNotFoundError:
        raise LfusdError(f"{path} is missing; {fix}") from None
    except (OSError, ValueError) as e:
        raise LfusdError(f"{path} is unreadable ({getattr(e, 'strerror', None) or str(e).splitlines()[0]}); {fix}") from None


def _cached(cache: dict, key, size: int, load):
    """``cache[key]``, loaded on a miss; keeps the ``size`` most recently used entries."""
    value = cache.pop(key) if key in cache else load()
    cache[key] = value
    while len(cache) > size:
        del cache[next(iter(cache))]
    return value

"""`Dataset`: read an lfusd dataset folder as NumPy arrays in the conventions of docs/CONVENTIONS.md.

Reads every format version lfusd wrote (lfusd.layout): 1 (rgb.png, rgb.exr, passes.exr,
motion.npz per view) and 2 (rgb.exr, gt.exr, motion.exr, passes.exr only with ``--keep-raw``;
the keys a render was asked for in the manifest's ``settings.keys``). Imports neither pxr, bpy
nor torch: ``from lfusd import Dataset`` stays light.
"""

from __future__ import annotations

import zipfile
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from . import passes, sensor, store
from .. import cpu_account, layout
from .folder import FrameMeta, Manifest, ObjectTable, read_frame_meta, read_manifest, read_objects
from .integrity import check_claims, complete_frames
from ..camera import Camera, Distortion, RigSpec, View, parse_view, ray_lengths
from ..errors import LfusdError
from ..keys import GT_RAW, IMAGE, MOTION, STATIC, get
from ..layout import frame_dir, view_key


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
    ``record`` is the typed manifest (:class:`lfusd.data.folder.Manifest`), ``manifest`` its JSON
    document as written.
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
        self.record: Manifest = read_manifest(self.root)
        self.manifest: dict = self.record.to_dict()
        rigs = list(self.record.rigs)
        rig = self._rig_arg
        if rig is None:
            if len(rigs) != 1:
                raise LfusdError(f"{self.root} holds rigs {', '.join(rigs)}; open one with Dataset(path, rig=NAME)")
            rig = rigs[0]
        if rig not in rigs:
            raise LfusdError(f"{self.root} has no rig {rig!r}; it has {', '.join(rigs)}")
        self.rig: RigSpec = self.record.rig_spec(rig, path)
        self.rig_name = rig
        self.table: ObjectTable = read_objects(self.root)
        self.classes: list[str] = list(self.table.classes)
        self._class_of_instance = np.zeros(max([o.id for o in self.table.objects], default=0) + 1, dtype=np.int32)
        for o in self.table.objects:
            self._class_of_instance[o.id] = o.class_id
        self.version = self.record.version  # the format version (lfusd.layout.FORMAT_VERSION)
        if self.version > layout.FORMAT_VERSION:
            raise LfusdError(f"{path} is format version {self.version}, newer than this lfusd reads ({layout.FORMAT_VERSION}); upgrade lfusd")
        # The keys the render was asked for (format version 2); None: every key it makes.
        self.keys: tuple[str, ...] | None = self.record.settings.keys
        self._objects: dict[int, DatasetObject] | None = None
        complete = self.record.complete_frames(rig)
        if scan or complete is None:  # manifests before the "complete" record: look at the folders
            # Sizes against each view's completion record (checksums: `lfusd verify --integrity`).
            complete = complete_frames(self.root, rig, list(self.record.frames), self.views)
        else:  # the manifest's record, against what is on disk before anything loops over it
            check_claims(self.root, rig, complete, self.views, "records as complete")
        self.frames: list[int] = [int(f) for f in complete]  # frames with every view rendered
        # Per-instance caches, most recent last: raw passes (t-1, t, t+1 of a view for the motion derivation), frame.json files.
        self._raw_cache: dict[str, dict[str, np.ndarray]] = {}
        self._meta_cache: dict[int, FrameMeta] = {}
        self._file_cache: dict[str, dict[str, np.ndarray]] = {}  # decoded gt.exr / motion.exr, most recent last

    # -- structure --------------------------------------------------------------------
    @property
    def views(self) -> list[View]:
        return self.rig.views

    @property
    def sensor(self) -> "sensor.SensorModel":
        """The sensor model of the ``rgb_noisy`` key (lfusd.data.sensor); LfusdError where the render had none."""
        doc = self.record.settings.get("sensor")
        if not isinstance(doc, dict):
            raise LfusdError(f"{self.root} was rendered without a sensor model, so it has no rgb_noisy; "
                             "render it again with --iso (e.g. --iso 800) into another folder")
        return sensor.SensorModel.from_dict(doc)

    @property
    def defocus(self) -> tuple[float, float]:
        """(aperture diameter, focus distance) in metres of the render's thin lens (``--fstop``, ``--focus``):
        the focal length over the f-number; LfusdError where the render was a pinhole."""
        doc = self.record.settings.get("defocus")
        if not isinstance(doc, dict) or not all(isinstance(doc.get(k), (int, float)) and doc[k] > 0 for k in ("fstop", "focus")):
            raise LfusdError(f"{self.root} was rendered with a pinhole camera, so it has no coc; "
                             "render it again with --fstop and --focus (e.g. --fstop 2.8 --focus 3) into another folder")
        return float(self.rig.focal_length_mm) * 1e-3 / float(doc["fstop"]), float(doc["focus"])

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

    def distortion(self, view: View) -> Distortion | None:
        """The view's lens distortion (``render-video --lens``: the manifest's ``settings.lens.views``,
        lfusd.camera.Distortion); None for a pinhole. Every pixel coordinate of the dataset is then a
        distorted one (docs/CONVENTIONS.md, "Lens distortion")."""
        self._check_view(view)
        doc = self.record.settings.get("lens")
        if not isinstance(doc, dict):
            return None
        try:
            return Distortion.from_dict(doc["views"][self.rig_name][view_key(view)])
        except (KeyError, TypeError, AttributeError):
            raise LfusdError(f"{self.root / layout.MANIFEST} records no lens of view {view_key(view)} in rig {self.rig_name!r}; "
                             "the manifest is damaged: render the dataset again into a new folder") from None

    @property
    def distorted(self) -> bool:
        """Whether the views were rendered through a lens distortion (--lens)."""
        return isinstance(self.record.settings.get("lens"), dict)

    def camera(self, frame: int, view: View) -> Camera:
        """The view's camera at ``frame`` (lfusd.camera.Camera: K, pose and lens): the one model to project
        points into its (distorted) pixels, cast their rays or backproject them."""
        return Camera(self.intrinsics(view), self.cam_to_world(frame, view), self.distortion(view))

    def cam_to_world(self, frame: int, view: View) -> np.ndarray:
        """4x4 OpenCV camera-to-world pose of ``view`` at ``frame`` (metres)."""
        self._check_view(view)
        return np.array(self._frame_meta(frame).cam_to_world[view_key(view)], dtype=np.float64)

    @property
    def objects(self) -> dict[int, DatasetObject]:
        """Instances by id, with their poses in every complete frame (read on first use, then kept)."""
        if self._objects is None:
            objs = {o.id: DatasetObject(o.id, o.prim_path, o.label, o.class_id) for o in self.table.objects}
            for f in self.frames:
                poses = self._frame_meta(f).object_poses
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
        a = self._read(frame, view, key)
        if a.shape[:2] != (self.rig.height, self.rig.width):  # the manifest's size is what K and every export use
            raise LfusdError(f"{self.view_dir(frame, view)} holds {key} of {a.shape[1]}x{a.shape[0]} px, but {self.root / layout.MANIFEST} "
                             f"says rig {self.rig_name!r} is {self.rig.width}x{self.rig.height}; the manifest is damaged: "
                             "render the dataset again into a new folder, or get it again whole")
        return a

    def _read(self, frame: int, view: View, key: str) -> np.ndarray:
        k = get(key)
        d = self.view_dir(frame, view)
        if self.keys is not None and key not in self.keys and k.storage.encoding != "raw":
            raise LfusdError(f"key {key!r} was not written to {self.root} (rendered with --keys {','.join(self.keys)}); "
                             f"render it into another folder with {key} in --keys")
        if k.stage == IMAGE:
            png = d / layout.RGB_PNG
            if key == "rgb" and png.is_file():
                from .formats import read_png

                return read_png(png)
            if not (d / layout.RGB_EXR).is_file():
                raise LfusdError(f"{d} has no {layout.RGB_EXR} for key {key!r}; rerun the render command to repair the view")
            rgb = passes.read_rgb_linear(d / layout.RGB_EXR)
            if key == "rgb_noisy":
                return sensor.noisy_srgb(self.sensor, rgb, tuple(view), frame)
            return rgb if key == "rgb_linear" else passes.linear_to_srgb8(rgb)
        if k.stage == MOTION:
            return self._motion(d, key)
        stored = self._static(str(d))
        if key in stored:
            return stored[key].copy()  # the cache must not be mutated by callers
        if k.stage == STATIC:
            info = passes.ViewInfo(self.intrinsics(view), self.baseline, self._class_of_instance, self.cam_to_world(frame, view),
                                   self.defocus if key == "coc" else None, self.distortion(view))
            return passes.DERIVED[key](stored, info)
        raw = self._raw(str(d))
        if key not in raw:
            raise LfusdError(f"{d / layout.PASSES_EXR} has no {key} pass; render the dataset with 'lfusd render-video'")
        return raw[key].copy()

    def raw_passes(self, frame: int, view: View):
        """The view's raw passes with its camera (the input of lfusd.truth.motion.derive_motion), decoded
        on first use of an image (lfusd.data.passes.LazyRawPasses); a missing file is an error now."""
        from .passes import LazyRawPasses, RawPasses

        d = str(self.view_dir(frame, view))
        self._raw_file(d)
        camera = self.camera(frame, view)

        def load() -> RawPasses:
            raw = self._raw(d)
            if "vector" not in raw:
                raise LfusdError(f"{Path(d) / layout.PASSES_EXR} has no vector pass; re-render with 'lfusd render-video'")
            return RawPasses(depth=raw["depth"], vector=raw["vector"], camera=camera, position=raw["position"],
                             instance=raw["instance"], next_position=raw.get("next_position"), prev_position=raw.get("prev_position"))

        width, height = self.resolution
        return LazyRawPasses(camera, (height, width), load)

    # -- internals ----------------------------------------------------------------------
    def _check_view(self, view: View) -> None:
        if tuple(view) not in set(self.views):
            raise LfusdError(f"view {view} is not in this {self.rig.rows}x{self.rig.cols} rig; rows 0-{self.rig.rows - 1}, cols 0-{self.rig.cols - 1}")

    def _frame_dir(self, frame: int) -> Path:
        return frame_dir(self.root, self.rig_name, frame)

    def _frame_meta(self, frame: int) -> FrameMeta:
        def load():
            return read_frame_meta(self._frame_dir(frame) / layout.FRAME_META, [view_key(v) for v in self.views],
                                   [o.prim_path for o in self.table.objects])

        return _cached(self._meta_cache, frame, 64, load)

    def _raw_file(self, view_dir: str) -> Path:
        """The view's passes.exr; an error naming the fix where a render removed it."""
        path = Path(view_dir) / layout.PASSES_EXR
        if self.version >= 2 and not path.is_file():
            raise LfusdError(f"the raw passes of {view_dir} were removed once its ground truth was written (rendered without "
                             "--keep-raw); they are needed here: render again with --keep-raw")
        return path

    def _raw(self, view_dir: str) -> dict[str, np.ndarray]:
        path = self._raw_file(view_dir)

        def read():
            with cpu_account.phase("read"):
                raw = passes.read_raw(path)
            if self.distorted:  # the OSL lens camera's depth pass is the distance along the pixel's ray
                dist = self.distortion(parse_view(Path(view_dir).name))
                h, w = raw["depth"].shape
                with np.errstate(invalid="ignore"):
                    raw["depth"] = (raw["depth"] / ray_lengths(self.rig.intrinsics(), h, w, dist)).astype(np.float32)
            return raw

        return _cached(self._raw_cache, view_dir, 4, read)

    def _static(self, view_dir: str) -> dict[str, np.ndarray]:
        """The stored static keys of a view: gt.exr (format version 2), else the raw passes (version 1, or
        a view whose ground truth is not written yet)."""
        gt = Path(view_dir) / layout.GT_FILE
        if self.version >= 2 and gt.is_file():
            return _cached(self._file_cache, str(gt), 4, lambda: store.read(gt))
        raw = self._raw(view_dir)
        return raw if self.version == 1 else {k: raw[k] for k in GT_RAW if k in raw}  # the material masks only with --materials

    def _motion(self, d: Path, key: str) -> np.ndarray:
        """One motion key of a view: from motion.exr (format version 2) or motion.npz (version 1)."""
        name = layout.MOTION_FILE if self.version >= 2 else layout.MOTION_FILE_V1
        path = d / name
        if not path.is_file():
            raise LfusdError(f"{d} has no {name} for key {key!r}; derive the motion keys with 'lfusd derive' (or render with 'lfusd render-video')")
        try:
            if self.version >= 2:
                keys = _cached(self._file_cache, str(path), 4, lambda: store.read(path))
                if key not in keys:
                    raise KeyError(key)
                return keys[key].copy()
            with np.load(path) as z:
                return z[key]
        except KeyError:
            raise LfusdError(f"{path} holds no {key!r}; derive it again with 'lfusd derive'") from None
        except (OSError, ValueError, EOFError, zipfile.BadZipFile) as e:
            raise LfusdError(f"{path} is unreadable ({e}); derive it again with 'lfusd derive'") from None


def _cached(cache: dict, key, size: int, load):
    """``cache[key]``, loaded on a miss; keeps the ``size`` most recently used entries."""
    value = cache.pop(key) if key in cache else load()
    cache[key] = value
    while len(cache) > size:
        del cache[next(iter(cache))]
    return value


def open_dataset(path, rig: str | None = None) -> Dataset:
    """``Dataset(path, rig=rig)`` with one-line errors naming the command-line fix: a missing
    folder, or a dataset of several rigs opened without ``--rig``."""
    p = Path(path)
    if not p.is_dir():
        raise LfusdError(f"dataset folder {p} does not exist; give the output folder of `lfusd render`")
    if rig is None:
        rigs = read_manifest(p).rigs
        if len(rigs) > 1:
            raise LfusdError(f"{p} holds rigs {', '.join(rigs)}; pick one with --rig NAME (rig=NAME from Python)")
    return Dataset(p) if rig is None else Dataset(p, rig=rig)


def open_datasets(path, rig: str | None = None) -> list[Dataset]:
    """One reader per rig of the dataset in ``path``: just ``rig``, or every rig when it is None or 'all'."""
    if rig not in (None, "all"):
        return [open_dataset(path, rig)]
    return [open_dataset(path, r) for r in read_manifest(path).rigs]  # the reader's one-line errors

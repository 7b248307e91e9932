"""A WebDataset / Hugging Face export (``lfusd export webdataset|hf``) read as a dataset.

:class:`ShardDataset` gives the reading interface of :class:`lfusd.Dataset` (``rig``, ``frames``,
``views``, ``keys``, ``read``, ``intrinsics``, ``cam_to_world``) over the export's tar shards, so
that ``lfusd.torch.LightFieldVideoDataset(ShardDataset(DEST))`` yields the items of the dataset
folder the export came from, and ``lfusd export``'s training cache can be made from shards
downloaded from remote storage (:func:`lfusd.data.cache.write_cache`). Every sample's arrays are
read where they lie in the tar (one seek, no extraction); ``rgb`` is decoded from its PNG, the
other stored keys from their ``.npy``, and the derived keys (``position``, ``disparity``,
``depth_euclidean``, ``semantic``) are computed from them as :class:`lfusd.Dataset` computes them
(:data:`lfusd.data.passes.DERIVED`), from the sample's K and pose, the rig's baseline and the
export's ``objects.json``. No pxr, bpy or torch.
"""

from __future__ import annotations

import io
import json
import os
import tarfile
from pathlib import Path

import numpy as np

from .. import keys as keyreg
from .. import layout
from ..camera import Camera, Distortion, RigSpec
from ..errors import LfusdError
from . import formats, passes

SHARDS, RIG = "shards", "lfusd_rig.json"  # lfusd.exports.webdataset's names (the data layer imports no exports)


class ShardDataset:
    """An lfusd WebDataset / Hugging Face export folder (``shards/*.tar``, ``lfusd_rig.json``,
    ``objects.json``) read like :class:`lfusd.Dataset` (see the module docstring). Frames are those
    whose every view has a sample."""

    def __init__(self, root):
        self.root = Path(root)
        rig_path = self.root / RIG
        if not rig_path.is_file():
            raise LfusdError(f"{self.root} has no {RIG}: it is not an lfusd webdataset/hf export (or one made before lfusd wrote it); "
                             "export the dataset again with 'lfusd export webdataset'")
        try:
            doc = json.loads(rig_path.read_text())
            self.rig = RigSpec.from_dict(doc["spec"])
            self.rig_name = str(doc["rig"])
        except (OSError, ValueError, KeyError, TypeError) as e:
            raise LfusdError(f"{rig_path} is unreadable ({e}); export the dataset again") from None
        self.baseline = float(self.rig.baseline)
        shards = sorted((self.root / SHARDS).glob("*.tar"))
        if not shards:
            raise LfusdError(f"{self.root / SHARDS} holds no .tar shard; download or export the shards first")
        self._handles: dict[Path, object] = {}  # open shards of this process
        self._pid = os.getpid()
        self._members: dict[str, dict[str, tuple[Path, int, int]]] = {}
        for path in shards:
            try:
                with tarfile.open(path, "r:") as tar:
                    for m in tar:
                        if not m.isfile():
                            continue
                        key, _, ext = m.name.partition(".")
                        self._members.setdefault(key, {})[ext] = (path, m.offset_data, m.size)
            except (OSError, tarfile.TarError) as e:
                raise LfusdError(f"{path} is not a readable tar shard ({e}); download or export it again") from None
        self._samples: dict[tuple[int, tuple[int, int]], dict] = {}
        for files in self._members.values():
            if "json" not in files:
                continue
            meta = json.loads(self._bytes(files["json"]))
            self._samples[(int(meta["frame"]), (int(meta["row"]), int(meta["col"])))] = {"meta": meta, "files": files}
        views = set(self.views)
        frames = {}
        for t, v in self._samples:
            frames.setdefault(t, set()).add(v)
        self.frames: list[int] = sorted(t for t, vs in frames.items() if vs >= views)
        if not self.frames:
            raise LfusdError(f"{self.root} holds no frame with all {len(views)} views; download every shard of the export")
        first = next(iter(self._samples.values()))["files"]
        stored = [ext[:-4] for ext in first if ext.endswith(".npy") and ext[:-4] in keyreg.KEYS]
        self._class_of_instance = None
        if (self.root / layout.OBJECTS).is_file():
            from .folder import read_objects

            table = read_objects(self.root)
            self.classes = list(table.classes)
            self._class_of_instance = np.zeros(max([o.id for o in table.objects], default=0) + 1, dtype=np.int32)
            for o in table.objects:
                self._class_of_instance[o.id] = o.class_id
        # a camera effect's keys (coc) need the render's effect settings, which a sample does not carry
        derived = [k for k, f in passes.DERIVED.items() if all(s in stored for s in keyreg.get(k).storage.sources)
                   and keyreg.get(k).effect is None and (k != "semantic" or self._class_of_instance is not None)]
        self.keys: tuple[str, ...] = tuple(k for k in keyreg.KEYS if k in {"rgb", *stored, *derived})

    @property
    def views(self) -> list[tuple[int, int]]:
        return self.rig.views

    @property
    def resolution(self) -> tuple[int, int]:
        return self.rig.width, self.rig.height

    def _bytes(self, where: tuple[Path, int, int]) -> bytes:
        if os.getpid() != self._pid:  # a forked worker opens its own files
            self._handles, self._pid = {}, os.getpid()
        path, offset, size = where
        f = self._handles.get(path)
        if f is None:
            f = self._handles[path] = open(path, "rb")
        f.seek(offset)
        return f.read(size)

    def _sample(self, frame: int, view) -> dict:
        s = self._samples.get((int(frame), (int(view[0]), int(view[1]))))
        if s is None or int(frame) not in self.frames:
            raise LfusdError(f"frame {frame}, view {tuple(view)} is not in the export {self.root} (frames {self.frames[0]}..{self.frames[-1]} "
                             f"of a {self.rig.rows}x{self.rig.cols} grid); download every shard")
        return s

    def intrinsics(self, view) -> np.ndarray:
        """3x3 OpenCV K of ``view`` (the sample's, exactly as exported)."""
        return np.array(self._sample(self.frames[0], view)["meta"]["K"], dtype=np.float64)

    def distortion(self, view) -> Distortion | None:
        """The view's lens distortion (the sample's ``dist``, OpenCV's distCoeffs); None for a pinhole."""
        coeffs = self._sample(self.frames[0], view)["meta"].get("dist")
        return Distortion(*map(float, coeffs)) if coeffs and any(coeffs) else None

    @property
    def distorted(self) -> bool:
        """Whether the exported views were rendered through a lens distortion (--lens)."""
        return any(self.distortion(v) is not None for v in self.views)

    def camera(self, frame: int, view) -> Camera:
        """The view's camera at ``frame`` (K, pose and lens: lfusd.camera.Camera)."""
        return Camera(self.intrinsics(view), self.cam_to_world(frame, view), self.distortion(view))

    def cam_to_world(self, frame: int, view) -> np.ndarray:
        """4x4 OpenCV camera-to-world pose of ``view`` at ``frame``."""
        return np.array(self._sample(frame, view)["meta"]["cam_to_world"], dtype=np.float64)

    def read(self, frame: int, view, key: str) -> np.ndarray:
        """One key of one view, as ``Dataset.read`` of the exported dataset returns it."""
        keyreg.get(key)
        if key not in self.keys:
            raise LfusdError(f"key {key!r} is not in the export {self.root} (it gives {', '.join(self.keys)}); export a dataset rendered with it")
        s = self._sample(frame, view)
        files = s["files"]
        if key == "rgb":
            return formats.decode_png(self._bytes(files["rgb.png"]), f"{self.root} sample {frame} {tuple(view)} rgb.png")
        if f"{key}.npy" in files:
            return np.load(io.BytesIO(self._bytes(files[f"{key}.npy"])), allow_pickle=False)
        sources = {src: self.read(frame, view, src) for src in keyreg.get(key).storage.sources}
        info = passes.ViewInfo(np.array(s["meta"]["K"], dtype=np.float64), self.baseline, self._class_of_instance,
                               np.array(s["meta"]["cam_to_world"], dtype=np.float64), dist=self.distortion(view))
        return passes.DERIVED[key](sources, info)

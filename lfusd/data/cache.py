"""The training cache (``lfusd export cache OUT DEST``): every key of every view decoded once into
uncompressed NumPy ``.npy`` arrays that a loader memory-maps and slices.

A dataset folder stores compressed EXR files and derives some keys on every read (``position``,
``disparity``, ``depth_euclidean``, ``semantic``): decoding dominates a training loader's time. The
cache decodes each key once and keeps exactly the array :meth:`lfusd.Dataset.read` returns (same
dtype, shape and values, NaN and inf included: ``rgb`` uint8 sRGB, ``rgb_linear`` float32, masks
``bool`` at one byte per pixel, integer ids int32), the views of a frame stacked, so a crop of
every view is one slice of one memory map. It costs the decoded size of its keys plus a 128-byte
``.npy`` header per file.

DEST holds:

- ``cache.json`` (:data:`RECORD`): format ``lfusd-cache``, the source (dataset id, folder, rig),
  the rig, the keys with their dtype and per-view shape, the views (row-major, the order of the
  stacked axis), the intrinsics, and per cached frame the size and sha256 of each of its files;
- ``manifest.json`` and ``objects.json``: the dataset's, copied (where the source has them);
- ``<frame:06d>/<key>.npy``: [V, H, W, *C] for the V views; ``<frame:06d>/cam_to_world.npy``:
  [V, 4, 4] float64.

A rerun completes and repairs: frames recorded with intact files (size and sha256) are kept, the
others written again; a cache of another dataset, rig or key set is refused. Files are written
under temporary names and renamed; a link where the cache writes is refused in one line. Imports
neither pxr, bpy nor torch.
"""

from __future__ import annotations

import json
import logging
import os
import re
import tempfile
from pathlib import Path

import numpy as np

from .. import keys as keyreg
from .. import layout
from ..camera import Camera, Distortion, RigSpec
from ..errors import LfusdError
from ..files import atomic_write, file_mode, sha256_of
from . import confined
from .folder import output_lock, resumable_folder

log = logging.getLogger(__name__)

FORMAT = "lfusd-cache"
VERSION = 1
RECORD = "cache.json"
POSES = "cam_to_world"  # the per-frame pose file's stem
_MAPS_OPEN = 256  # memory maps kept open per process (each is one mapping of the process)


def frame_folder(frame: int) -> str:
    """The folder of one frame in a cache: ``000001``."""
    return f"{int(frame):06d}"


def cacheable_keys(ds, keys=None) -> list[str]:
    """The keys a cache of ``ds`` holds, in registry order: ``keys`` (checked), or every key
    ``ds.read`` returns on its first frame and view except Blender's raw passes."""
    if not ds.frames:
        raise LfusdError(f"dataset {getattr(ds, 'root', '')} has no completely rendered frame yet; finish its render first")
    if keys is not None:
        asked = {keyreg.get(k).name for k in keys}
        out = [k for k in keyreg.KEYS if k in asked]  # registry order: the same set is the same cache whatever order it was asked in
        t, v = ds.frames[0], tuple(ds.views[0])
        for k in out:
            ds.read(t, v, k)  # a key the dataset cannot give is its reader's one-line error now, not mid-way
        return out
    wanted = ds.keys if getattr(ds, "keys", None) is not None else keyreg.check_wanted(None, motion=True, keep_raw=False)
    wanted = set(wanted) | ({"rgb"} if "rgb_linear" in wanted else set())
    t, v = ds.frames[0], tuple(ds.views[0])
    out = []
    for k in keyreg.KEYS.values():
        if k.name not in wanted or k.storage.encoding == "raw":
            continue
        try:
            ds.read(t, v, k.name)
        except (LfusdError, KeyError):  # e.g. motion keys of a still render whose manifest lists no keys
            continue
        out.append(k.name)
    return out


def _source(ds) -> dict:
    manifest = getattr(ds, "manifest", None) or {}
    return {"dataset_id": manifest.get("id"), "root": str(Path(getattr(ds, "root", "")).resolve()), "rig": getattr(ds, "rig_name", ds.rig.name)}


def _read_record(path: Path) -> dict:
    try:
        doc = json.loads(path.read_text())
    except (OSError, ValueError) as e:
        raise LfusdError(f"{path} is unreadable ({getattr(e, 'strerror', None) or e}); move the cache folder aside and make it again") from None
    if not isinstance(doc, dict) or doc.get("format") != FORMAT:
        raise LfusdError(f"{path.parent} holds a {RECORD} that is not an lfusd training cache's; choose another folder")
    if doc.get("version") != VERSION:
        raise LfusdError(f"{path.parent} is a training cache of version {doc.get('version')}; this lfusd reads version {VERSION}: make it again into a new folder")
    return doc


def _frame_intact(dest: Path, entry: dict) -> bool:
    for name, f in entry.get("files", {}).items():
        p = dest / name
        if confined.is_link(p) or not p.is_file() or p.stat().st_size != f["bytes"] or sha256_of(p) != f["sha256"]:
            return False
    return True


# The temporaries of a killed cache run: ".<name>.npy.<8 random>.tmp" (a frame's file), ".cache.json.<8 random>.tmp".
_TMP = re.compile(r"\.(?:[A-Za-z0-9_]+\.npy|cache\.json|manifest\.json|objects\.json)\.[a-z0-9_]{8}\.tmp")


def _remove_temporaries(folder: Path) -> None:
    """Remove what a killed run of the cache left in ``folder``: only its temporaries' names, never through a link."""
    with os.scandir(folder) as it:
        for e in it:
            if _TMP.fullmatch(e.name) and not e.is_dir(follow_symlinks=False):
                os.unlink(e.path)


def _write_frame(ds, dest: Path, t: int, views, keys) -> tuple[dict, list[str]]:
    """Write one frame's files, view after view (each view's files decoded once for all its keys),
    straight into memory-mapped temporaries renamed when whole; returns (files record, missing keys)."""
    rel = {name: f"{frame_folder(t)}/{name}.npy" for name in (POSES, *keys)}
    for r in rel.values():
        if confined.is_link(dest / r):
            raise confined.link_error(dest / r)
    maps: dict[str, np.ndarray] = {}
    tmps: dict[str, str] = {}
    missing: list[str] = []

    def open_map(name: str, first: np.ndarray) -> np.ndarray:
        fd, tmp = tempfile.mkstemp(dir=dest / frame_folder(t), prefix=f".{name}.npy.", suffix=".tmp")
        os.close(fd)
        tmps[name] = tmp
        return np.lib.format.open_memmap(tmp, mode="w+", dtype=first.dtype, shape=(len(views), *first.shape))

    try:
        for i, v in enumerate(views):
            pose = np.asarray(ds.cam_to_world(t, v), np.float64)
            if i == 0:
                maps[POSES] = open_map(POSES, pose)
            maps[POSES][i] = pose
            for k in keys:
                if k in missing:
                    continue
                try:
                    a = np.asarray(ds.read(t, v, k))
                except LfusdError:
                    missing.append(k)  # e.g. a motion key the derivation could not write for this frame
                    continue
                if i == 0:
                    maps[k] = open_map(k, a)
                maps[k][i] = a
        files = {}
        for name, m in maps.items():
            m.flush()
            del m
            if name in missing:
                continue
            path = Path(tmps[name])
            os.chmod(path, file_mode())
            files[rel[name]] = {"bytes": path.stat().st_size, "sha256": sha256_of(path)}
            os.replace(path, dest / rel[name])
        return files, missing
    finally:
        maps.clear()
        for tmp in tmps.values():
            Path(tmp).unlink(missing_ok=True)  # those not renamed: a failed or missing key


def write_cache(ds, dest, frame: int | None = None, keys=None) -> list[Path]:
    """Make or complete the training cache of ``ds`` in ``dest`` (see the module docstring); returns
    the folders of the frames it holds. ``frame``: only that frame; ``keys``: the keys to cache
    (default: :func:`cacheable_keys`). A rerun keeps the intact frames and writes the others."""
    dest = Path(dest)
    if confined.is_link(dest):
        raise confined.link_error(dest)
    record = resumable_folder(dest, RECORD, "cache", "lfusd training cache", _read_record)
    if record is not None and confined.is_link(dest / RECORD):
        raise confined.link_error(dest / RECORD)
    keys = cacheable_keys(ds, keys if keys is not None else (record["keys"] if record else None))
    if not keys:
        raise LfusdError(f"dataset {getattr(ds, 'root', '')} has no key to cache; render it first")
    frames = ds.frames if frame is None else [frame]
    if frame is not None and frame not in ds.frames:
        raise LfusdError(f"frame {frame} is not in the dataset (it has frames {ds.frames[0]}..{ds.frames[-1]}); pick one of those")
    views = [tuple(int(x) for x in v) for v in ds.views]
    h, w = ds.rig.height, ds.rig.width
    source = _source(ds)
    key_info = {k: {"dtype": keyreg.get(k).dtype, "shape": [h, w, *keyreg.get(k).shape]} for k in keys}
    if record is not None:
        theirs = (record["source"].get("dataset_id"), record["source"].get("rig"), record["keys"], [tuple(v) for v in record["views"]])
        if theirs != (source["dataset_id"], source["rig"], keys, views):
            raise LfusdError(f"{dest} is a training cache of another dataset, rig or key set ({record['source'].get('rig')}: "
                             f"{','.join(record['keys'])}); choose a new folder for this one")
    try:
        dest.mkdir(parents=True, exist_ok=True)
    except OSError as e:
        raise LfusdError(f"cannot create cache folder {dest} ({e.strerror}); choose a writable place") from None
    with output_lock(dest):
        for name in (RECORD, layout.MANIFEST, layout.OBJECTS):
            if confined.is_link(dest / name):
                raise confined.link_error(dest / name)
        _remove_temporaries(dest)
        doc = record or {"format": FORMAT, "version": VERSION, "source": source, "rig": ds.rig.to_dict(), "keys": keys,
                         "key_info": key_info, "views": [list(v) for v in views],
                         "intrinsics": [np.asarray(ds.intrinsics(v), np.float64).tolist() for v in views], "frames": {},
                         # render-video --lens: each view's model (lfusd.camera.Distortion.to_dict); absent for pinholes
                         **({"distortion": [ds.distortion(v).to_dict() for v in views]} if getattr(ds, "distorted", False) else {})}
        root = getattr(ds, "root", None)
        for name in (layout.MANIFEST, layout.OBJECTS):  # the dataset's own records, copied as they are
            src = Path(root) / name if root is not None else None
            if src is not None and src.is_file() and not (dest / name).is_file():
                atomic_write(dest / name, src.read_bytes())
        done = []
        for t in frames:
            fdir = dest / frame_folder(t)
            if confined.is_link(fdir):
                raise confined.link_error(fdir)
            entry = doc["frames"].get(str(t))
            if entry is not None and _frame_intact(dest, entry):
                done.append(fdir)
                continue
            fdir.mkdir(exist_ok=True)
            _remove_temporaries(fdir)
            files, missing = _write_frame(ds, dest, t, views, keys)
            doc["frames"][str(t)] = {"files": files, "missing": missing}
            atomic_write(dest / RECORD, json.dumps(doc, indent=1))
            log.info("cached frame %s (%d keys, %d views)", t, len(keys) - len(missing), len(views))
            done.append(fdir)
        atomic_write(dest / RECORD, json.dumps(doc, indent=1))
    return done


class TrainingCache:
    """A training cache read through memory maps: the reading interface of :class:`lfusd.Dataset`
    (``rig``, ``frames``, ``views``, ``keys``, ``read``, ``intrinsics``, ``cam_to_world``) plus
    :meth:`window`, a crop of several views in one slice.

    :meth:`read` returns a view of the map, copy-on-write (writing into it changes no file); each
    process opens its own maps on first use (a DataLoader's workers included)."""

    def __init__(self, root):
        self.root = Path(root)
        path = self.root / RECORD
        if not path.is_file():
            raise LfusdError(f"{self.root} holds no {RECORD}, so it is no training cache; make one with 'lfusd export cache OUT {self.root}'")
        self.record = _read_record(path)
        self.rig = RigSpec.from_dict(self.record["rig"])
        self.rig_name = self.record["source"]["rig"]
        self.baseline = float(self.rig.baseline)
        self.keys: tuple[str, ...] = tuple(self.record["keys"])
        self.views = [tuple(v) for v in self.record["views"]]
        self._index = {v: i for i, v in enumerate(self.views)}
        self.frames: list[int] = sorted(int(t) for t in self.record["frames"])
        self._missing = {int(t): set(e.get("missing", ())) for t, e in self.record["frames"].items()}
        self._k = np.asarray(self.record["intrinsics"], np.float64)
        self._maps: dict[tuple[int, str], np.ndarray] = {}
        self._memo: dict[tuple, list[int]] = {}
        self._pid = os.getpid()

    @property
    def resolution(self) -> tuple[int, int]:
        """(width, height) in pixels."""
        return self.rig.width, self.rig.height

    def view_index(self, view) -> int:
        """The position of ``view`` on the stacked axis; LfusdError for a view outside the grid."""
        try:
            return self._index[tuple(int(x) for x in view)]
        except KeyError:
            raise LfusdError(f"view {tuple(view)} is not in this {self.rig.rows}x{self.rig.cols} cache") from None

    def _indices(self, views) -> list[int]:
        """Positions of ``views`` on the stacked axis (remembered per selection: a loader asks for the same views every item)."""
        sel = tuple(tuple(v) for v in views)
        idx = self._memo.get(sel)
        if idx is None:
            idx = self._memo[sel] = [self.view_index(v) for v in sel]
        return idx

    def maps(self, frame: int, key: str) -> np.ndarray:
        """The copy-on-write memory map [V, H, W, *C] of ``key`` at ``frame`` (``cam_to_world``: [V, 4, 4])."""
        if os.getpid() != self._pid:  # a forked worker opens its own maps
            self._maps, self._pid = {}, os.getpid()
        ck = (int(frame), key)
        m = self._maps.pop(ck, None)
        if m is None:
            if int(frame) not in self._missing:
                raise LfusdError(f"frame {frame} is not in the cache {self.root} (frames {self.frames[0]}..{self.frames[-1]}); "
                                 "rerun 'lfusd export cache' to add it")
            if key != POSES and key not in self.keys:
                raise LfusdError(f"key {key!r} is not in the cache {self.root} (it holds {', '.join(self.keys)}); "
                                 "make a cache with it into a new folder")
            if key in self._missing[int(frame)]:
                raise LfusdError(f"the dataset gave no {key!r} for frame {frame}, so the cache {self.root} has none; read another frame")
            path = self.root / frame_folder(frame) / f"{key}.npy"
            try:
                m = np.load(path, mmap_mode="c", allow_pickle=False)  # copy-on-write: writing an item never reaches the file
            except (OSError, ValueError) as e:
                raise LfusdError(f"{path} is unreadable ({getattr(e, 'strerror', None) or e}); rerun 'lfusd export cache' to repair the cache") from None
        self._maps[ck] = m
        while len(self._maps) > _MAPS_OPEN:
            del self._maps[next(iter(self._maps))]
        return m

    def read(self, frame: int, view, key: str) -> np.ndarray:
        """One key of one view, equal to ``Dataset.read`` of the source (a copy-on-write view of the map)."""
        return self.maps(frame, key)[self.view_index(view)]

    def window(self, frame: int, key: str, views, top: int, left: int, height: int, width: int) -> np.ndarray:
        """``key`` of ``views`` cropped to rows top..top+height, columns left..left+width: one
        array [V, height, width, *C], a view of the map where the views are consecutive (no copy:
        the map is copy-on-write, so writing into it changes no file), else one copy."""
        m = self.maps(frame, key)
        idx = self._indices(views)
        rows, cols = slice(top, top + height), slice(left, left + width)
        if idx == list(range(idx[0], idx[0] + len(idx))):
            return m[idx[0] : idx[0] + len(idx), rows, cols]
        return m[idx, rows, cols]  # advanced indexing on the view axis: one copy

    def intrinsics(self, view) -> np.ndarray:
        """3x3 OpenCV K of ``view``."""
        return self._k[self.view_index(view)].copy()

    def cam_to_world(self, frame: int, view) -> np.ndarray:
        """4x4 OpenCV camera-to-world pose of ``view`` at ``frame``."""
        return np.array(self.maps(frame, POSES)[self.view_index(view)])

    @property
    def distorted(self) -> bool:
        """Whether the cached views were rendered through a lens distortion (--lens)."""
        return "distortion" in self.record

    def distortion(self, view) -> Distortion | None:
        """The view's lens distortion (lfusd.camera.Distortion); None for a pinhole."""
        return Distortion.from_dict(self.record["distortion"][self.view_index(view)]) if self.distorted else None

    def camera(self, frame: int, view) -> Camera:
        """The view's camera at ``frame`` (K, pose and lens: lfusd.camera.Camera)."""
        return Camera(self.intrinsics(view), self.cam_to_world(frame, view), self.distortion(view))


def is_cache(path) -> bool:
    """Whether ``path`` is a folder holding a training cache's record."""
    return (Path(path) / RECORD).is_file()

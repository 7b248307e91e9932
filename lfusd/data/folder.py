"""The dataset folder: the one place that opens, creates, locks, resumes and atomically writes it.

Every writer of a dataset folder (the render, the ground-truth derivation, the rig study, a recipe,
the exports) and every reader goes through here:

- :func:`atomic_write` (defined in :mod:`lfusd.files`, below every layer, so that authoring uses
  the same one): a file appears whole or not at all (text, bytes, or a writer that takes a path),
  readable like the folder's other files;
- (a reader of one rig / of every rig is :func:`lfusd.data.dataset.open_dataset` /
  :func:`lfusd.data.dataset.open_datasets`, beside the reader, which this module does not import);
- the typed records of its metadata: :class:`Manifest` (with :class:`RenderSettings`),
  :class:`ObjectTable` and :class:`FrameMeta`, each read through the security checks of
  :mod:`lfusd.data.metadata` (names that become paths, sizes that become loops) and written back
  exactly as read (the fields a record does not type keep their place and value);
- :class:`DatasetLike`: what reads like a :class:`lfusd.data.dataset.Dataset` (exports,
  evaluation and verification take any such object), and :func:`require_pinhole`, the one refusal
  of a lens-distorted one by whatever computes with K alone;
- creating, resuming and locking: :func:`resumable_folder` (the one rule for the output folder a
  render, a rig study or a recipe resumes; :func:`existing_dataset` is the render's),
  :func:`output_lock` (one writer per folder), :func:`new_folder` (an export target written whole
  or not at all).

Imports only the standard library and lfusd's base modules at module level (the Blender worker
imports it), never pxr, bpy or torch.
"""

from __future__ import annotations

import contextlib
import dataclasses
import errno
import fcntl
import json
import os
import re
import shutil
import stat
import sys
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable, Protocol, runtime_checkable

from .. import layout
from ..files import atomic_write, file_mode  # noqa: F401  (the folder's writers take them from here)
from ..errors import LfusdError


@runtime_checkable
class DatasetLike(Protocol):
    """Something that reads like a :class:`lfusd.data.dataset.Dataset`: what the exports, the
    evaluation and the verifier need (tests give them analytic fakes)."""

    frames: list[int]

    @property
    def rig(self) -> Any: ...

    @property
    def views(self) -> list: ...

    def read(self, frame: int, view, key: str): ...

    def intrinsics(self, view): ...

    def cam_to_world(self, frame: int, view): ...


def require_pinhole(ds, needs: str, fix: str = "render it again without --lens into another folder") -> None:
    """Refuse, in one line, a dataset (any :class:`DatasetLike`) rendered through a lens distortion
    (``render-video --lens``) for ``needs`` (what it is and why it needs a pinhole, e.g. "the plane sweep
    (it shifts views by disparity)"): something that computes with K alone or shifts views by
    disparity would be silently wrong on distorted pixels. ``fix``: what the user can do instead."""
    if getattr(ds, "distorted", False):
        where = getattr(ds, "root", None) or "the dataset"
        raise LfusdError(f"{where} was rendered through a lens distortion (--lens), and {needs} needs a pinhole dataset; {fix}")


# ---- typed records of the folder's metadata ---------------------------------------------------

def _plain(v):
    """A record's value as JSON holds it (tuples as lists, records as objects)."""
    if isinstance(v, _Record):
        return v.to_dict()
    if isinstance(v, (list, tuple)):
        return [_plain(x) for x in v]
    if isinstance(v, dict):
        return {k: _plain(x) for k, x in v.items()}
    return v


@dataclass(frozen=True)
class _Record:
    """Base of the typed records. A record keeps the keys of its document in order (``_order``) and
    the fields it does not type (``_extra``), so :meth:`to_dict` gives back exactly the document
    :meth:`from_dict` read; a field the document lacks reads as its default. :meth:`new` makes a
    record whose document holds the fields given, in the order given (the order lfusd writes them)."""

    _order: tuple[str, ...] = field(default=(), repr=False, compare=False, kw_only=True)
    _extra: dict = field(default_factory=dict, repr=False, compare=False, kw_only=True)

    @classmethod
    def _fields(cls) -> dict[str, dataclasses.Field]:
        return {f.name: f for f in dataclasses.fields(cls) if not f.name.startswith("_")}

    @classmethod
    def new(cls, **values):
        """A record holding ``values`` (field name -> value), written in that order."""
        return cls(**values, _order=tuple(values))

    @classmethod
    def _build(cls, doc: dict, **typed):
        names = cls._fields()
        values = {n: doc[n] for n in names if n in doc} | {n: v for n, v in typed.items() if n in doc}
        return cls(**values, _order=tuple(doc), _extra={k: v for k, v in doc.items() if k not in names})

    def to_dict(self) -> dict:
        """The record as its JSON document: its keys in their order, then any field set since (not at its default)."""
        names = self._fields()
        out = {}
        for k in self._order:
            if k in names:
                out[k] = _plain(getattr(self, k))
            elif k in self._extra:
                out[k] = self._extra[k]
        for k, f in names.items():
            if k not in out:
                default = f.default_factory() if f.default_factory is not dataclasses.MISSING else f.default
                if getattr(self, k) != default:
                    out[k] = _plain(getattr(self, k))
        return out


def _ints(x) -> bool:
    return isinstance(x, list) and all(isinstance(f, int) and not isinstance(f, bool) for f in x)


@dataclass(frozen=True)
class RenderSettings(_Record):
    """``settings`` of the manifest: everything that affects pixels (a resume must match all of it)."""

    stage_id: str | None = None  # digest of the stage's files
    versions: dict = field(default_factory=dict)  # lfusd and Blender
    rigs: dict = field(default_factory=dict)  # rig name -> RigSpec.to_dict()
    samples: int | None = None
    motion: bool = False  # rendered with the motion AOVs (render-video)
    light: str | None = None
    format_version: int | None = None
    keys: tuple[str, ...] | None = None  # the keys stored (format version 2); None: every key it makes
    keep_raw: bool = False
    stage_frames: tuple[int, int] | None = None  # an animated stage's range; None: a static stage

    @classmethod
    def from_dict(cls, doc: dict) -> "RenderSettings":
        """The record of a checked ``settings`` object."""
        keys = doc.get("keys")
        return cls._build(doc, keys=tuple(keys) if isinstance(keys, list) else keys,
                          stage_frames=tuple(doc["stage_frames"]) if isinstance(doc.get("stage_frames"), list) else doc.get("stage_frames"))

    def get(self, name: str, default=None):
        """A setting by name, typed or not (for comparing two renders' settings)."""
        return self.to_dict().get(name, default)


MANIFEST_FIX = "restore it, or render the dataset again into a new folder"


@dataclass(frozen=True)
class Manifest(_Record):
    """``manifest.json``: the dataset's identity, stage, rigs, frames, settings and record of
    complete frames, fields in the order lfusd writes them."""

    format: str = layout.FORMAT
    version: int = 1  # the format version (lfusd.layout.FORMAT_VERSION); 1 when the field is absent
    id: str | None = None  # proof that lfusd wrote the folder
    stage: dict = field(default_factory=dict)  # path, sha256, files
    world: dict | None = None  # the stage's up axis and units, and the map into lfusd's world
    rigs: tuple[str, ...] = ()
    frames: tuple[int, ...] = ()
    settings: RenderSettings = field(default_factory=RenderSettings)
    device: str | None = None
    complete: dict = field(default_factory=dict)  # rig -> frames whose every view is complete
    software: dict = field(default_factory=dict)
    layout: str | None = None
    certificate: dict | None = None  # lfusd verify's per-key figures (lfusd.truth.verify.record_certificate)

    @classmethod
    def from_dict(cls, doc, path: str | Path = "manifest.json") -> "Manifest":
        """The record of a parsed manifest, or LfusdError naming the file and the first field
        that is not what lfusd writes (lfusd.data.metadata's checks first: they guard paths and sizes)."""
        from .metadata import validate_manifest

        path = Path(path)
        if not isinstance(doc, dict) or doc.get("format") != layout.FORMAT:
            raise LfusdError(f"{path} is not an lfusd dataset manifest; open the output folder of 'lfusd render'")
        validate_manifest(doc, path)

        def bad(what: str) -> LfusdError:
            return LfusdError(f"{path} is damaged ({what}); {MANIFEST_FIX}")

        rigs, settings = doc.get("rigs"), doc.get("settings")
        if not isinstance(rigs, list) or not rigs or not all(isinstance(r, str) and r for r in rigs):
            raise bad("'rigs' is not a list of rig names" if "rigs" in doc else "no 'rigs'")
        if not _ints(doc.get("frames")):
            raise bad("'frames' is not a list of frame numbers" if "frames" in doc else "no 'frames'")
        if not isinstance(settings, dict):
            raise bad("'settings' is not a record" if "settings" in doc else "no 'settings'")
        if not isinstance(settings.get("rigs"), dict) or not all(isinstance(settings["rigs"].get(r), dict) for r in rigs):
            raise bad("'settings.rigs' lacks a record of each rig")
        keys = settings.get("keys")
        if keys is not None and not (isinstance(keys, list) and all(isinstance(k, str) for k in keys)):
            raise bad("'settings.keys' is not a list of key names")
        version = doc.get("version", 1)
        if not isinstance(version, int) or isinstance(version, bool) or version < 1:
            raise bad("'version' is not a format version")
        complete = doc.get("complete", {})
        if not isinstance(complete, dict) or not all(_ints(v) for v in complete.values()):
            raise bad("'complete' is not a list of frames per rig")
        if not isinstance(doc.get("stage", {}), dict):
            raise bad("'stage' is not a record")
        return cls._build(doc, rigs=tuple(rigs), frames=tuple(doc["frames"]), settings=RenderSettings.from_dict(settings))

    def complete_frames(self, rig: str) -> list[int] | None:
        """The frames of ``rig`` the manifest records as complete; None when it records none (older manifests)."""
        return list(self.complete[rig]) if rig in self.complete else None

    def rig_spec(self, rig: str, path: str | Path = "manifest.json"):
        """The RigSpec of ``rig``, or LfusdError naming the manifest."""
        from ..camera import RigSpec

        try:
            spec = RigSpec.from_dict(self.settings.rigs[rig])
            grid_ok = all(isinstance(x, int) and not isinstance(x, bool) and x > 0 for x in (spec.rows, spec.cols, spec.width, spec.height))
            float(spec.baseline)
        except (KeyError, TypeError, ValueError, LfusdError):  # RigSpec checks its own fields, in its own words
            grid_ok = False
        if not grid_ok:
            raise LfusdError(f"{path} holds no readable record of rig {rig!r}; {MANIFEST_FIX}") from None
        return spec

    def to_json(self) -> str:
        """The text of ``manifest.json``."""
        return json.dumps(self.to_dict(), indent=1)


@dataclass(frozen=True)
class ObjectRow(_Record):
    """One instance of the object table: id, USD prim path, label, class id and the meshes drawn for it."""

    id: int = 0
    prim_path: str = ""
    label: str = ""
    class_id: int = 0
    meshes: tuple[str, ...] = ()


@dataclass(frozen=True)
class ObjectTable(_Record):
    """``objects.json``: the class table and the instance table."""

    classes: tuple[str, ...] = ()
    objects: tuple[ObjectRow, ...] = ()

    @classmethod
    def from_dict(cls, doc, path: str | Path = "objects.json") -> "ObjectTable":
        """The record of a parsed object table, or LfusdError naming the file (lfusd.data.metadata's checks first)."""
        from .metadata import validate_objects

        validate_objects(doc, path)
        try:
            rows = []
            for o in doc["objects"]:
                if not (isinstance(o["prim_path"], str) and isinstance(o["label"], str) and int(o["class_id"]) == o["class_id"] >= 0):
                    raise ValueError(o)
                rows.append(ObjectRow._build(o, meshes=tuple(o["meshes"]) if isinstance(o.get("meshes"), list) else o.get("meshes")))
        except (KeyError, TypeError, ValueError, IndexError):
            raise LfusdError(f"{path} is not an lfusd object table; rerun the render that made the dataset") from None
        return cls._build(doc, classes=tuple(doc["classes"]), objects=tuple(rows))

    def to_json(self) -> str:
        """The text of ``objects.json``."""
        return json.dumps(self.to_dict(), indent=1)


@dataclass(frozen=True)
class FrameMeta(_Record):
    """``frame.json`` of one rig and frame: each view's camera-to-world pose and each object's
    world pose (4x4 matrices as nested lists, OpenCV camera frame)."""

    frame: int = 0
    time_code: float = 0
    cam_to_world: dict = field(default_factory=dict)  # view key (lfusd.layout.view_key) -> 4x4
    object_poses: dict = field(default_factory=dict)  # prim path -> 4x4

    @classmethod
    def from_dict(cls, doc, path: str | Path = "frame.json", views=(), prims=()) -> "FrameMeta":
        """The record of a parsed frame.json, or LfusdError naming the file: lfusd.data.metadata's
        checks, then every pose a 4x4 matrix and one for each view key of ``views`` and prim of ``prims``."""
        import numpy as np

        from .metadata import validate_frame_meta

        path = Path(path)
        validate_frame_meta(doc, path)
        fix = "delete it and rerun the render to write it again"
        try:
            for name, m in (*doc["cam_to_world"].items(), *doc["object_poses"].items()):
                if np.asarray(m, dtype=np.float64).shape != (4, 4):
                    raise ValueError(name)
        except (KeyError, TypeError, ValueError, AttributeError):
            raise LfusdError(f"{path} is damaged (its poses are not 4x4 matrices); {fix}") from None
        missing = [v for v in views if v not in doc["cam_to_world"]] + [p for p in prims if p not in doc["object_poses"]]
        if missing:
            raise LfusdError(f"{path} is damaged (no pose of {missing[0]}); {fix}")
        return cls._build(doc)

    def to_json(self) -> str:
        """The text of ``frame.json`` (compact: one per frame)."""
        return json.dumps(self.to_dict())


def read_json(path: Path, fix: str):
    """The JSON in ``path``, or LfusdError naming the file and ``fix``."""
    try:
        return json.loads(path.read_text())
    except FileNotFoundError:
        raise LfusdError(f"{path} is missing; {fix}") from None
    except (OSError, ValueError) as e:
        raise LfusdError(f"{path} is unreadable ({getattr(e, 'strerror', None) or str(e).splitlines()[0]}); {fix}") from None


def read_manifest(root: str | Path) -> Manifest:
    """The manifest of the dataset in ``root``, its structure checked: every command that reads a
    dataset reads it here (through :class:`lfusd.data.dataset.Dataset` or directly), so a missing,
    corrupt or incomplete manifest is one LfusdError naming the file, whoever reads it."""
    root = Path(root)
    path = root / layout.MANIFEST
    if not root.is_dir():
        raise LfusdError(f"dataset folder {root} does not exist; give the output folder of 'lfusd render'")
    if not path.is_file():
        raise LfusdError(f"{root} holds no lfusd dataset (no {layout.MANIFEST}); render one with 'lfusd render'")
    return Manifest.from_dict(read_json(path, MANIFEST_FIX), path)


def read_objects(root: str | Path) -> ObjectTable:
    """The object table of the dataset in ``root``, checked."""
    path = Path(root) / layout.OBJECTS
    return ObjectTable.from_dict(read_json(path, "rerun the render that made the dataset (it rewrites the object table)"), path)


def read_frame_meta(path: str | Path, views=(), prims=()) -> FrameMeta:
    """One frame.json, checked (see :meth:`FrameMeta.from_dict`)."""
    path = Path(path)
    if not path.is_file():
        raise LfusdError(f"{path} is missing; rerun the render to complete this frame")
    return FrameMeta.from_dict(read_json(path, "delete it and rerun the render to write it again"), path, views, prims)


# ---- creating, resuming and locking -----------------------------------------------------------


def resumable_folder(out: str | Path, record: str, noun: str, kind: str, read: Callable[[Path], Any], foreign: bool = False):
    """The record of the output folder ``out`` that a run resumes (a render's dataset, a rig study,
    a recipe's dataset), read by ``read(path of record)``, which refuses a record lfusd did not
    write or that asks for other settings; None for a missing or empty folder (its lock aside).

    One-line LfusdError for a file, a planted ``.lock`` link, an unreadable folder, and (unless
    ``foreign``) a folder holding other files but no ``record``. ``noun``: what the folder is for
    ('dataset', 'study'); ``kind``: what its record proves it holds ('lfusd dataset', 'rig study').
    Reads only."""
    from . import confined

    out = Path(out)
    if out.exists() and not out.is_dir():
        raise LfusdError(f"output {out} is a file; give a folder for the {noun}")
    if not out.is_dir():
        return None
    if confined.is_link(out / layout.LOCK):  # planted: the lock would write through it
        raise confined.link_error(out / layout.LOCK)
    try:
        entries = [p for p in out.iterdir() if p.name != layout.LOCK]
    except OSError as e:
        raise LfusdError(f"cannot read output folder {out} ({e.strerror}); fix its permissions or choose another -o folder") from None
    path = out / record
    if not entries or (foreign and not path.is_file()):
        return None
    if not path.is_file() or path.is_symlink():
        raise LfusdError(f"output folder {out} is not empty and holds no {kind}; choose an empty or new folder")
    return read(path)


def existing_dataset(out: str | Path) -> Manifest | None:
    """The manifest of the lfusd dataset in ``out`` that a render resumes or may overwrite; None for
    a missing or empty folder. Raises LfusdError for anything lfusd cannot prove it wrote: a file, a
    folder with other files, a manifest without lfusd's format field and a dataset id. Reads only."""
    return resumable_folder(out, layout.MANIFEST, "dataset", "lfusd dataset", _dataset_manifest)


def _dataset_manifest(path: Path) -> Manifest:
    """The manifest a render may resume or overwrite: lfusd's format and a dataset id, and the
    checks of lfusd.data.metadata (names that become paths, sizes that become loops)."""
    from .metadata import validate_manifest

    out = path.parent
    try:
        manifest = json.loads(path.read_text())
    except (OSError, ValueError) as e:
        raise LfusdError(f"{path} is unreadable ({getattr(e, 'strerror', None) or e}), so {out} is not provably an lfusd dataset; "
                         "move the folder aside or choose another -o folder") from None
    if not isinstance(manifest, dict) or manifest.get("format") != layout.FORMAT:
        raise LfusdError(f"output folder {out} holds a {layout.MANIFEST} that is not an lfusd dataset's; choose another -o folder "
                         "(lfusd deletes nothing it did not write, --overwrite included)")
    if not manifest.get("id"):
        raise LfusdError(f"output folder {out} holds an lfusd dataset of an older format (no dataset id); choose another -o folder "
                         "or move it aside")
    validate_manifest(manifest, path)
    return Manifest._build(manifest, rigs=tuple(manifest.get("rigs", ())), frames=tuple(manifest.get("frames", ())),
                           settings=RenderSettings.from_dict(manifest.get("settings", {})))


@contextlib.contextmanager
def output_lock(out: str | Path):
    """Hold OUT/.lock (an advisory flock) while writing the dataset in ``out``: one writer per
    folder. The kernel drops the lock of a process that dies, so a stale lock is simply taken.
    The lock file is opened without following links: a ``.lock`` link is refused, its target untouched."""

    from . import confined

    out = Path(out)
    path = out / layout.LOCK
    try:
        fd = os.open(path, os.O_RDWR | os.O_CREAT | getattr(os, "O_NOFOLLOW", 0) | getattr(os, "O_CLOEXEC", 0), file_mode())
    except OSError as e:
        if e.errno == errno.ELOOP:
            raise confined.link_error(path) from None
        raise LfusdError(f"cannot write to {out} ({e.strerror or e}); make it writable or choose another -o folder") from None
    try:
        if not stat.S_ISREG(os.fstat(fd).st_mode):
            raise LfusdError(f"{path} is not a file; remove it, then rerun")
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            holder = os.pread(fd, 4096, 0).decode(errors="replace").strip() or "unknown"
            pid, _, command = holder.partition(" ")
            raise LfusdError(f"output folder {out} is being written by process {pid} ({command or 'unknown command'}); "
                             "wait for it to finish or stop it, or choose another -o folder") from None
        os.ftruncate(fd, 0)
        os.pwrite(fd, f"{os.getpid()} {' '.join(['lfusd', *sys.argv[1:]]) if sys.argv else 'lfusd'}\n".encode(), 0)
        yield
    finally:
        os.close(fd)  # closing drops the flock


def _random8() -> str:
    """Eight random characters of the alphabet ``tempfile`` uses (the random part of lfusd's temporary names)."""
    import secrets

    return "".join(secrets.choice("abcdefghijklmnopqrstuvwxyz0123456789_") for _ in range(8))


def _partial_pattern(dest: Path) -> re.Pattern:
    """The name of a partial folder of a write to ``dest``: ``.<name>.partial-<pid>-<8 random>``."""
    return re.compile(rf"\.{re.escape(dest.name)}\.partial-(\d+)-[a-z0-9_]{{8}}")


def remove_stale_partials(dest: Path) -> None:
    """Remove the partial folders of writes to ``dest`` that were killed: only a name lfusd makes
    (``.<name>.partial-<pid>-<8 random>``, :func:`new_folder`), a real folder (never a link) owned by
    this user, of a process no longer running; so that a rerun leaves nothing behind."""
    pattern = _partial_pattern(dest)
    for p in dest.parent.iterdir() if dest.parent.is_dir() else ():
        m = pattern.fullmatch(p.name)
        if not m:
            continue
        try:
            st = os.lstat(p)
        except OSError:
            continue
        if not stat.S_ISDIR(st.st_mode) or st.st_uid != os.getuid():
            continue  # a link, a file, or another user's folder: not ours to remove
        try:
            os.kill(int(m[1]), 0)
        except ProcessLookupError:
            shutil.rmtree(p, ignore_errors=True)
        except (PermissionError, OverflowError):
            pass  # another user's running process, or no pid


@contextlib.contextmanager
def new_folder(dest: str | Path, what: str = "export"):
    """A new folder ``dest`` written whole or not at all (an export): yields the hidden path
    ``.<name>.partial-<pid>-<8 random>`` beside it for the writer to create and fill, renamed to ``dest`` when
    the block ends, removed when it fails (an OSError becomes one line). The partial folders of
    killed writes to ``dest`` are removed first; an existing ``dest`` is refused."""
    from .formats import why_unwritable

    dest = Path(dest)
    if dest.exists():
        raise LfusdError(f"{what} target {dest} already exists; choose a new folder or remove it first")
    try:
        dest.parent.mkdir(parents=True, exist_ok=True)
    except OSError as e:
        raise LfusdError(f"cannot create {what} target {dest} ({e.strerror}): {why_unwritable(dest)}") from None
    remove_stale_partials(dest)
    tmp = dest.parent / f".{dest.name}.partial-{os.getpid()}-{_random8()}"
    try:
        yield tmp
        tmp.rename(dest)
    except OSError as e:
        raise LfusdError(f"cannot write {what} {dest} ({e.strerror or e}): {why_unwritable(tmp / 'x')}") from None
    finally:
        if tmp.is_dir() and not tmp.is_symlink():
            shutil.rmtree(tmp, ignore_errors=True)

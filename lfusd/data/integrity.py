"""Completion records: a view is complete when its files are what its record says, not when its folder exists.

Each view folder holds ``view.json`` (:data:`lfusd.layout.VIEW_RECORD`)::

    {"version": 2, "files": {"rgb.exr": {"size": N, "sha256": HEX}, "gt.exr": {..., "checked": PIXELS},
                             "passes.exr": {"size": N, "header": HEX, "pixels": HEX, "removed": true},
                             "motion.exr": {..., "checked": PIXELS, "inputs": {"prev": HEX|null, "cur": HEX, "next": HEX|null}}}}

The renderer's files (rgb.exr, passes.exr) are recorded last inside the view's temporary folder,
before the atomic rename; the derivation adds gt.exr and motion.exr (atomically) with the pixels
it compared when it read them back, and the motion entry with the digests of the raw passes it
was derived from, so motion derived before a neighbouring frame existed, or from passes since
re-rendered, is known to be stale. Raw passes are recorded by the digests of their header and of
their chunks (:func:`file_entry`, XXH3): the chunks' digest names their pixels, one hash for both. Raw passes removed after derivation keep their entry, marked
``removed``, so the digests of their neighbours' inputs stay checkable. Version 1 records (format
version 1: rgb.png, rgb.exr, passes.exr, motion.npz) and raw passes recorded by the file's sha256
and a digest of the decoded pixels (before format 2's chunk digests) are read as they were
written. sha256 for the files a dataset keeps (anyone can check them with sha256sum) because it is the
fastest stdlib hash on CPUs with SHA extensions (measured 1.7 GB/s here, blake2b 1.2 GB/s). No pxr, bpy or torch.
"""

from __future__ import annotations

import hashlib
import json
import os
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from .. import cpu_account, layout
from ..layout import frame_dir, view_key
from .folder import atomic_write

VERSION = 2
RENDER_FILES = (layout.RGB_EXR, layout.PASSES_EXR)  # written by the renderer, recorded on commit
RENDER_FILES_V1 = (layout.RGB_PNG, layout.RGB_EXR, layout.PASSES_EXR)
MOTION_FILES = (layout.MOTION_FILE, layout.MOTION_FILE_V1)  # checked against their inputs, not as rendered files

# In-process memo of digests by (path, size, mtime, ctime, inode): one run hashes each file once
# however often it checks it; a new process (the next run, `verify --integrity`) hashes again.
_DIGESTS: dict[tuple, dict[str, str]] = {}


def file_entry(path: str | Path, split: bool | None = None) -> dict | None:
    """``{"size", "sha256"}`` of a file, or None when it is missing or unreadable.

    ``split`` (default: for raw passes, ``passes.exr``): ``{"size", "header", "pixels"}`` instead,
    digests (:data:`RAW_DIGEST`) of the EXR's headers and offset tables and of its chunks
    (:func:`lfusd.data.passes.chunks_start`), each byte hashed once: a view rendered again has another
    header (Blender stamps the date and render time into it) but, measured, the same pixels, so its
    neighbours' motion, derived from those pixels, stays current. A file whose chunks cannot be
    located gets ``sha256`` alone."""
    p = Path(path)
    if split is None:
        split = p.name == layout.PASSES_EXR
    try:
        with open(p, "rb") as f:
            st = os.fstat(f.fileno())
            memo = (str(p), split, st.st_size, st.st_mtime_ns, st.st_ctime_ns, st.st_ino)
            digests = _DIGESTS.get(memo)
            if digests is None:
                start = None
                if split:
                    from .passes import chunks_start

                    start = chunks_start(p)
                with cpu_account.phase("hashing"):
                    digests = _raw_digests(f, start) if start is not None else {"sha256": hashlib.file_digest(f, "sha256").hexdigest()}
                if len(_DIGESTS) > 100_000:
                    _DIGESTS.clear()
                _DIGESTS[memo] = digests
    except OSError:
        return None
    return {"size": st.st_size, **digests}


# The raw passes' digest: XXH3 (128 bits), hashed in place in the page cache (mmap). They are
# transient, never published, and their digests only tell accidental damage and another render apart,
# which 128 bits of XXH3 do; at about 7 GB/s against sha256's 1.1-1.7 it takes 0.014 instead of
# 0.07 core-s per 1024x1024 view (benchmarks/bench_reference.py). Digests name their algorithm.
RAW_DIGEST = "xxh3_128"


def _raw_digests(f, start: int) -> dict:
    """``{"header", "pixels"}``: the digests of an open file's bytes before and from ``start``."""
    import mmap

    import xxhash

    try:
        with mmap.mmap(f.fileno(), 0, access=mmap.ACCESS_READ) as m, memoryview(m) as view:
            return {"header": f"{RAW_DIGEST}:{xxhash.xxh3_128(view[:start]).hexdigest()}",
                    "pixels": f"{RAW_DIGEST}:{xxhash.xxh3_128(view[start:]).hexdigest()}"}
    except (OSError, ValueError):  # a file system that cannot map files: read it in pieces
        f.seek(0)
        header, pixels = xxhash.xxh3_128(f.read(start)), xxhash.xxh3_128()
        while piece := f.read(1 << 22):
            pixels.update(piece)
        return {"header": f"{RAW_DIGEST}:{header.hexdigest()}", "pixels": f"{RAW_DIGEST}:{pixels.hexdigest()}"}


def read_record(view_dir: str | Path) -> dict | None:
    """The view's record, or None when it is missing or unreadable."""
    try:
        rec = json.loads((Path(view_dir) / layout.VIEW_RECORD).read_text())
    except (OSError, ValueError):
        return None
    return rec if isinstance(rec, dict) and isinstance(rec.get("files"), dict) else None


def write_record(view_dir: str | Path, record: dict) -> None:
    """Write ``view.json`` under a temporary name and rename it into place."""
    with cpu_account.phase("commit"):
        atomic_write(Path(view_dir) / layout.VIEW_RECORD, json.dumps(record, indent=1), prefix=".view.", suffix=".json", sync=True)


def record_render(view_dir: str | Path) -> dict:
    """Record the renderer's files of a freshly assembled view folder (call it last, before the rename)."""
    d = Path(view_dir)
    files = {}
    for name in RENDER_FILES:
        entry = file_entry(d / name)
        if entry is None:
            raise FileNotFoundError(f"{d / name} is missing")
        files[name] = entry
    if (d / layout.GEOMETRY).is_file():  # render-video's triangles of the frame (exact occlusion)
        files[layout.GEOMETRY] = file_entry(d / layout.GEOMETRY)
    record = {"version": VERSION, "files": files}
    write_record(d, record)
    return record


def record_files(view_dir: str | Path, add: dict[str, dict] | None = None, remove: tuple[str, ...] = (),
                 annotate: dict[str, dict] | None = None) -> dict:
    """Add (or replace) entries ``{name: extra fields}`` for files now in the view folder, mark
    ``remove`` as removed (keeping their size and digest) and add fields to the entries in
    ``annotate``, in one atomic write of the record."""
    d = Path(view_dir)
    record = read_record(d) or {"version": VERSION, "files": {}}
    for name, extra in (annotate or {}).items():
        if name in record["files"]:
            record["files"][name] = {**record["files"][name], **extra}
    for name, extra in (add or {}).items():
        entry = file_entry(d / name)
        if entry is None:
            raise FileNotFoundError(f"{d / name} is missing")
        record["files"][name] = {**entry, **extra}
    for name in remove:
        if name in record["files"]:
            record["files"][name] = {**record["files"][name], "removed": True}
    write_record(d, record)
    return record


def record_motion(view_dir: str | Path, inputs: dict, extra: dict | None = None) -> None:
    """Add (or replace) the motion file's entry, with the digests of the raw passes it came from
    (``motion.exr``; ``motion.npz`` in a version 1 record)."""
    d = Path(view_dir)
    record_files(d, {motion_file(read_record(d)): {**(extra or {}), "inputs": inputs}})


def motion_file(record: dict | None) -> str:
    """The motion keys' file of a view with this record: motion.exr, or motion.npz in format version 1."""
    return layout.MOTION_FILE_V1 if record is not None and record.get("version", 1) == 1 else layout.MOTION_FILE


def present(record: dict | None, name: str) -> bool:
    """Whether the record lists ``name`` as a file of the view (not removed)."""
    entry = (record or {}).get("files", {}).get(name)
    return entry is not None and not entry.get("removed")


def _mismatch(d: Path, name: str, want: dict | None, deep: bool) -> str | None:
    """Why ``name`` does not match its record entry ``want`` (None: it matches)."""
    if want is None:
        return f"{name} is not in the record"
    p = d / name
    try:
        size = p.stat().st_size
    except OSError:
        return f"{name} is missing"
    if size != want.get("size"):
        return f"{name} has {size} bytes, the record {want.get('size')}"
    if deep:
        # a record holds the whole file's sha256, or (raw passes) those of its header and its chunks
        got = file_entry(p, split="sha256" not in want)
        if got is None:
            return f"{name} is unreadable"
        if any(got.get(k) != want.get(k) for k in ("sha256", "header", "pixels") if k in got):
            return f"{name} differs from its recorded checksum"
    return None


def render_problems(view_dir: str | Path, deep: bool = True) -> list[str]:
    """Why a view is not complete: no folder, no record, or a renderer's file not matching it.

    ``deep`` compares checksums, not only sizes."""
    d = Path(view_dir)
    if not d.is_dir():
        return ["the view folder is missing"]
    rec = read_record(d)
    if rec is None:
        return [f"it has no readable {layout.VIEW_RECORD}"]
    if rec.get("version", 1) == 1:
        return [m for name in RENDER_FILES_V1 if (m := _mismatch(d, name, rec["files"].get(name), deep))]
    # Version 2: every file the record lists (bar motion, checked against its inputs) must match;
    # the static keys are in gt.exr or, before derivation and with --keep-raw, in passes.exr.
    if not (present(rec, layout.GT_FILE) or present(rec, layout.PASSES_EXR)):
        return [f"it has neither {layout.GT_FILE} nor {layout.PASSES_EXR} in its record"]
    return [m for name, want in rec["files"].items()
            if name not in MOTION_FILES and not want.get("removed") and (m := _mismatch(d, name, want, deep))]


IMAGE_FILES = (layout.RGB_EXR, layout.RGB_PNG)  # the beauty render's files: only a render with the image rebuilds them
FULL, RAW = "full", "raw"  # what a view needs rendered again: the image and the raw passes, or the raw passes alone


def repair_need(view_dir: str | Path) -> str | None:
    """What must be rendered again to rebuild a view (None: its files match its record): FULL
    without a folder, a readable record or an intact image (and for format version 1); RAW when only
    what is derived from the raw passes (gt.exr) or kept raw passes are missing or damaged."""
    problems = render_problems(view_dir)
    if not problems:
        return None
    rec = read_record(view_dir)
    if rec is None or rec.get("version", 1) == 1:
        return FULL
    d = Path(view_dir)
    files = rec["files"]
    if any(name in files and not files[name].get("removed") and _mismatch(d, name, files[name], True) for name in IMAGE_FILES):
        return FULL
    if not any(name in files for name in IMAGE_FILES):
        return FULL  # no image on record at all (a removed one is on record: its keys were not asked for)
    return RAW


def passes_on_disk(view_dir: str | Path) -> bool:
    """Whether the view's raw passes are on disk and match its record."""
    rec = read_record(view_dir)
    return present(rec, layout.PASSES_EXR) and _mismatch(Path(view_dir), layout.PASSES_EXR, rec["files"][layout.PASSES_EXR], True) is None


def damaged_files(view_dir: str | Path) -> list[str]:
    """The files the view's record lists (not removed) that do not match it: missing, another size
    or another checksum. Motion files count too (their inputs are the derivation's to judge)."""
    d = Path(view_dir)
    rec = read_record(d)
    if rec is None:
        return []
    return [name for name, want in rec["files"].items() if not want.get("removed") and _mismatch(d, name, want, True)]


def view_complete(view_dir: str | Path) -> bool:
    """The view's rendered files all match its record (sizes and checksums)."""
    return not render_problems(view_dir)


def complete_frames(root: str | Path, rig: str, frames, views) -> list[int]:
    """The ``frames`` whose every view's files match their records by size (a quick check:
    checksums are for the planner and `lfusd verify --integrity`). A frame without a folder is
    passed over with one listing of the rig's folder, so a long frame list costs nothing per frame."""
    on_disk = _folders(Path(root) / rig)
    return [f for f in frames if layout.frame_name(f) in on_disk
            and not any(render_problems(frame_dir(root, rig, f) / view_key(v), deep=False) for v in views)]


# A manifest may claim more than was rendered (a render stopped early), but not absurdly more: past
# this many missing views, and ten times more missing than present, its claim is refused before
# any work scales with it (a 2x2 dataset claiming a 512x512 grid, a listing of a million frames).
MAX_MISSING_VIEWS = 10_000


def _folders(path: Path) -> set[str]:
    """The names of the real folders in ``path`` (none when it is missing or not a folder)."""
    try:
        with os.scandir(path) as it:
            return {e.name for e in it if e.is_dir(follow_symlinks=False)}
    except OSError:
        return set()


def check_claims(root: str | Path, rig: str, frames, views, what: str = "lists") -> None:
    """Refuse, in one line, a manifest whose frames x views of ``rig`` exceed what is on disk by
    more than :data:`MAX_MISSING_VIEWS` and tenfold (two folder listings: the rig's, and the
    first present frame's), before a reader loops over them."""
    from ..errors import LfusdError

    root = Path(root)
    frames, n_views = list(frames), len(views)
    on_disk = _folders(root / rig)
    present = [f for f in frames if layout.frame_name(f) in on_disk]
    have = _folders(frame_dir(root, rig, present[0])) if present else set()
    views_there = sum(view_key(v) in have for v in views) if present else 0
    claimed = len(frames) * n_views
    there = len(present) * views_there  # at most: the first present frame's views in each present frame
    if claimed - there > MAX_MISSING_VIEWS and claimed > 10 * there:
        raise LfusdError(f"{root / layout.MANIFEST} {what} {len(frames)} frames x {n_views} views of rig {rig!r}, but {len(present)} "
                         f"of those frames are on disk, with {views_there} views in the first; finish its render (a rerun "
                         "resumes it), or get the dataset again whole")


def pixels_digest(arrays: dict) -> str:
    """sha256 of the pixels of a view's raw passes (name -> NumPy array), independent of the file's
    header: Blender stamps the date and render time into it, so a view rendered again has other
    bytes but, measured, the same pixels."""
    h = hashlib.sha256()
    with cpu_account.phase("hashing"):
        for name in sorted(arrays):
            a = arrays[name]
            h.update(f"{name}:{a.dtype.str}:{a.shape}".encode())
            h.update(memoryview(np.ascontiguousarray(a)).cast("B"))  # the bytes of tobytes(), without a copy
    return h.hexdigest()


def motion_inputs(passes_of: dict[str, Path | None]) -> dict[str, str | None]:
    """Digests of the raw passes a derivation reads: {"prev", "cur", "next"} -> digest or None (no such frame).

    The pixels digest the record holds (the chunks' digest of :func:`file_entry`, or in records made
    before it :func:`pixels_digest`), else the file's; raw passes removed after derivation count by the digest their record keeps."""
    out = {}
    for k in ("prev", "cur", "next"):
        p = passes_of.get(k)
        digest = None
        if p is not None:
            kept = ((read_record(Path(p).parent) or {}).get("files") or {}).get(Path(p).name) or {}
            if kept.get("pixels"):
                digest = kept["pixels"]
            elif kept.get("removed"):
                digest = kept.get("sha256")
            else:
                entry = file_entry(p) or {}
                digest = entry.get("pixels") or entry.get("sha256")
        out[k] = digest
    return out


def motion_problem(view_dir: str | Path, inputs: dict | None = None, deep: bool = True) -> str | None:
    """Why a view's motion.npz is not current (None: it is): missing, damaged, or derived from other passes.

    ``inputs``: the digests of the passes it should come from now (see :func:`motion_inputs`)."""
    d = Path(view_dir)
    rec = read_record(d)
    name = motion_file(rec)
    want = (rec or {"files": {}})["files"].get(name)
    if want is None:
        return f"{name} is missing" if not (d / name).is_file() else f"{name} is not in the record"
    bad = _mismatch(d, name, want, deep)
    if bad:
        return bad
    if inputs is not None and want.get("inputs") != inputs:
        old = want.get("inputs") or {}
        which = [k for k in ("prev", "cur", "next") if old.get(k) != inputs.get(k)]
        return f"{name} was derived from other raw passes ({', '.join(which) or 'inputs'} changed)"
    return None


@dataclass
class Problem:
    """One view whose files do not match its record."""

    rig: str
    frame: int
    view: tuple[int, int]
    what: str

    def __str__(self) -> str:
        return f"rig {self.rig} frame {self.frame} view {self.view[0]},{self.view[1]}: {self.what}"


def check_dataset(root: str | Path, rig: str | None = None, progress=None, frames=None, views=None) -> tuple[int, list[Problem]]:
    """Check every view of every frame in the manifest (or only ``frames`` and ``views``) against
    its record, without reading pixels.

    Rendered files must match; with motion keys (render-video), the motion file must exist, match,
    and come from the current raw passes of the view and its neighbours. Returns (views checked, problems).
    """
    from ..errors import LfusdError
    from ..keys import KEYS, MOTION
    from .folder import read_manifest

    root = Path(root)
    manifest = read_manifest(root)  # the reader's checks and one-line errors
    rigs = list(manifest.rigs)
    if rig not in (None, "all"):
        if rig not in rigs:
            raise LfusdError(f"{root} has no rig {rig!r}; it has {', '.join(rigs)}")
        rigs = [rig]
    frames_all = [int(f) for f in manifest.frames]
    chosen = frames_all if frames is None else [f for f in frames_all if f in set(frames)]
    wanted = manifest.settings.keys  # format version 2: the keys asked for (None: version 1, every key)
    motion = manifest.settings.motion and (wanted is None or any(KEYS[k].stage == MOTION for k in wanted if k in KEYS))
    checked, problems = 0, []
    for name in rigs:
        spec = manifest.rig_spec(name, root / layout.MANIFEST)
        check_claims(root, name, chosen, spec.views if views is None else [v for v in spec.views if tuple(v) in {tuple(w) for w in views}])
        for f in chosen:
            for v in spec.views if views is None else [v for v in spec.views if tuple(v) in {tuple(w) for w in views}]:
                progress and progress(name, f, v)
                d = frame_dir(root, name, f) / view_key(v)
                checked += 1
                bad = render_problems(d)
                problems += [Problem(name, f, tuple(v), b) for b in bad]
                if bad or not motion:
                    continue
                passes = {k: frame_dir(root, name, g) / view_key(v) / layout.PASSES_EXR if g in frames_all else None
                          for k, g in (("prev", f - 1), ("cur", f), ("next", f + 1))}
                m = motion_problem(d, motion_inputs(passes))
                if m:
                    problems.append(Problem(name, f, tuple(v), m))
    return checked, problems

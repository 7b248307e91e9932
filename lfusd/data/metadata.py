"""The grammar of a dataset's metadata, checked before any of it names a file.

``manifest.json``, ``objects.json`` and ``frame.json`` may come from someone else: every name in
them that becomes part of a path (rig names, frame numbers, view keys) and every number that
sizes an allocation or a loop (grid, resolution, frame count, instance ids) is checked here
against what lfusd writes, so a crafted ``../victim`` or ``/home/user`` rig, a frame list of 1e9
entries or an instance id of 1e12 is refused in one line instead of used. No pxr, bpy or torch.
"""

from __future__ import annotations

import math
import re
from pathlib import Path

from .. import layout
from ..errors import LfusdError

# Bounds well beyond any real dataset, small enough that using them cannot exhaust the machine.
MAX_RIGS = 1000
MAX_FRAMES = layout.MAX_FRAMES
FRAME_RANGE = (-999_999, 9_999_999)  # f{frame:06d} stays a plain name (no separator) in this range
MAX_GRID = 512  # rows or cols of a rig
MAX_SIDE = 65_536  # pixels, width or height
MAX_INSTANCE_ID = 1 << 24  # the class lookup of Dataset is one int32 per id
VIEW_KEY = re.compile(r"\d{2,3}_\d{2,3}")


def _bad(path, what: str, fix: str = "it was not written by lfusd or is damaged; rerun the render that made the dataset "
                                       "into a new folder") -> LfusdError:
    return LfusdError(f"{path}: {what}; {fix}")


def check_rig_name(name, path="manifest.json") -> str:
    """``name`` if it is a rig name lfusd writes (a USD prim name: letters, digits and _, not
    first a digit; so no separator, ``..`` or absolute path), else LfusdError."""
    if not (isinstance(name, str) and 0 < len(name) <= 255 and name.isascii() and name.replace("_", "a").isalnum()
            and not name[0].isdigit()):
        raise _bad(path, f"rig name {str(name)[:80]!r} is not a rig name lfusd writes (letters, digits and _)")
    return name


def check_frame(frame, path="manifest.json") -> int:
    """``frame`` if it is an integer frame number in :data:`FRAME_RANGE`, else LfusdError."""
    if isinstance(frame, bool) or not isinstance(frame, int) or not FRAME_RANGE[0] <= frame <= FRAME_RANGE[1]:
        raise _bad(path, f"frame {str(frame)[:40]!r} is not a frame number lfusd writes")
    return frame


def _frames(value, path, what: str) -> list[int]:
    if not isinstance(value, list) or len(value) > MAX_FRAMES:
        raise _bad(path, f"{what} is not a list of at most {MAX_FRAMES} frame numbers")
    return [check_frame(f, path) for f in value]


def _rig_spec(name: str, spec, path) -> None:
    if not isinstance(spec, dict):
        raise _bad(path, f"the record of rig {name!r} is not an object")
    for key, top in (("rows", MAX_GRID), ("cols", MAX_GRID), ("width", MAX_SIDE), ("height", MAX_SIDE)):
        v = spec.get(key)
        if isinstance(v, bool) or not isinstance(v, int) or not 1 <= v <= top:
            raise _bad(path, f"rig {name!r} has {key} {str(v)[:40]!r}, not an integer in 1-{top}")
    if spec.get("name", name) != name:
        raise _bad(path, f"rig {name!r} is recorded under another name ({str(spec.get('name'))[:80]!r})")


def validate_manifest(manifest, path="manifest.json") -> dict:
    """Check a parsed ``manifest.json`` before anything uses it: its rigs (names and grid
    sizes), frames and complete frames, and the key list; return it, or raise LfusdError naming
    the first field that is not what lfusd writes. Fields lfusd does not turn into paths or
    sizes are left to their readers."""
    if not isinstance(manifest, dict):
        raise _bad(path, "it is not a JSON object")
    rigs = manifest.get("rigs", [])
    if not isinstance(rigs, list) or len(rigs) > MAX_RIGS:
        raise _bad(path, f"'rigs' is not a list of at most {MAX_RIGS} rig names")
    for r in rigs:
        check_rig_name(r, path)
    settings = manifest.get("settings", {})
    if not isinstance(settings, dict):
        raise _bad(path, "'settings' is not an object")
    specs = settings.get("rigs", {})
    if not isinstance(specs, dict) or len(specs) > MAX_RIGS:
        raise _bad(path, "'settings.rigs' is not an object of rig records")
    for name, spec in specs.items():
        _rig_spec(check_rig_name(name, path), spec, path)
    missing = [r for r in rigs if r not in specs]
    if missing:
        raise _bad(path, f"rig {missing[0]!r} has no record in 'settings.rigs'")
    _frames(manifest.get("frames", []), path, "'frames'")
    complete = manifest.get("complete", {})
    if not isinstance(complete, dict):
        raise _bad(path, "'complete' is not an object")
    for name, frames in complete.items():
        _frames(frames, path, f"'complete' of rig {check_rig_name(name, path)!r}")
    keys = settings.get("keys")
    if keys is not None and (not isinstance(keys, list) or not all(isinstance(k, str) for k in keys) or len(keys) > 100):
        raise _bad(path, "'settings.keys' is not a list of key names")
    from ..keys import KEYS

    unknown = [k for k in keys or () if k not in KEYS]
    if unknown:
        raise _bad(path, f"'settings.keys' names {unknown[0][:40]!r}, not a key lfusd writes")
    _stage(manifest.get("stage", {}), path)
    version = manifest.get("version", 1)
    if isinstance(version, bool) or not isinstance(version, int):
        raise _bad(path, f"'version' {str(version)[:20]!r} is not an integer")
    return manifest


def _stage(stage, path) -> None:
    """The ``stage`` record: the stage's path and digest as strings, its files a record per file name."""
    if not isinstance(stage, dict):
        raise _bad(path, "'stage' is not an object")
    for key in ("path", "sha256"):
        if key in stage and not isinstance(stage[key], str):
            raise _bad(path, f"'stage.{key}' is not a string")
    files = stage.get("files", {})
    if not isinstance(files, dict) or not all(isinstance(k, str) and isinstance(v, dict) for k, v in files.items()):
        raise _bad(path, "'stage.files' is not an object of file records")


def validate_objects(table, path="objects.json") -> dict:
    """Check a parsed ``objects.json``: a class list of strings, objects with integer ids in
    0-:data:`MAX_INSTANCE_ID`, class ids into that list, prim paths and labels as strings."""
    if not isinstance(table, dict) or not isinstance(table.get("classes"), list) or not isinstance(table.get("objects"), list):
        raise _bad(path, "it is not an lfusd object table (classes and objects)")
    classes = table["classes"]
    if not all(isinstance(c, str) for c in classes):
        raise _bad(path, "a class name is not a string")
    for o in table["objects"]:
        if not isinstance(o, dict):
            raise _bad(path, "an object entry is not an object")
        i, c = o.get("id"), o.get("class_id")
        if isinstance(i, bool) or not isinstance(i, int) or not 0 <= i <= MAX_INSTANCE_ID:
            raise _bad(path, f"object id {str(i)[:40]!r} is not an integer in 0-{MAX_INSTANCE_ID}")
        if isinstance(c, bool) or not isinstance(c, int) or not 0 <= c < max(len(classes), 1):
            raise _bad(path, f"object {i} has class id {str(c)[:40]!r}, not an index into its {len(classes)} classes")
        if not isinstance(o.get("prim_path"), str) or not isinstance(o.get("label", ""), str):
            raise _bad(path, f"object {i} has no prim path or label string")
    return table


def _matrix(m) -> bool:
    return (isinstance(m, list) and len(m) == 4 and all(isinstance(r, list) and len(r) == 4 for r in m)
            and all(isinstance(x, (int, float)) and not isinstance(x, bool) and math.isfinite(x) for r in m for x in r))


def validate_frame_meta(meta, path: str | Path = "frame.json") -> dict:
    """Check a parsed ``frame.json``: its frame number, view keys (``RR_CC``) with 4x4 finite
    poses, and object poses as 4x4 finite matrices by prim path."""
    if not isinstance(meta, dict):
        raise _bad(path, "it is not a JSON object", "delete it and rerun the render to write it again")
    check_frame(meta.get("frame", 0), path)
    cams, poses = meta.get("cam_to_world"), meta.get("object_poses", {})
    if not isinstance(cams, dict) or not isinstance(poses, dict):
        raise _bad(path, "it lacks its camera or object poses", "delete it and rerun the render to write it again")
    for key, m in cams.items():
        if not VIEW_KEY.fullmatch(str(key)) or not _matrix(m):
            raise _bad(path, f"view {str(key)[:20]!r} has no 4x4 pose lfusd writes", "delete it and rerun the render to write it again")
    for prim, m in poses.items():
        if not _matrix(m):
            raise _bad(path, f"object {str(prim)[:80]!r} has no 4x4 pose", "delete it and rerun the render to write it again")
    return meta

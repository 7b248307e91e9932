"""Opening stages with clear errors, and their frame range."""

from __future__ import annotations

import hashlib
import logging
import os
import re
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from pxr import Gf, Sdf, Tf, Usd, UsdGeom, UsdUtils

from ..errors import LfusdError

log = logging.getLogger(__name__)


def _one_line(text: str) -> str:
    """A pxr diagnostic on one line: whitespace runs folded, object addresses dropped."""
    return re.sub(r"\s*<0x[0-9a-fA-F]+>", "", " ".join(str(text).split()))


@contextmanager
def usd_warnings(report: bool = True, composition: bool = True):
    """Report the warnings pxr posts inside the block as one ``lfusd: warning:`` line each (through
    logging) instead of its own multi-line output on stderr, each once (a stage opened twice posts
    its composition errors twice, differing only in the stage named); errors stay pxr's (they
    raise). ``report=False`` drops them: for a stage whose arcs another stage composes again.
    ``composition`` False: leave out the composition errors a stage reports as it opens (its caller
    states them itself, :func:`composition_problem`)."""
    with Tf.DiagnosticTrap() as trap:
        try:
            yield
        finally:
            seen = set()
            for w in trap.GetWarnings() if report else ():
                if not composition and w.sourceFunction.endswith("UsdStage::_ReportErrors"):
                    continue
                line = _one_line(w.commentary)
                # the same broken arc seen from another stage or prim (the asset, a layer over it,
                # the prim that references it) is one problem: one line
                same = re.sub(r"^In <[^>]*>: |\s*\((instantiating|recomposing) stage on stage @[^@]*@\)$", "", line)
                if same not in seen:
                    seen.add(same)
                    log.warning("USD: %s", line)
            for st in trap.GetStatuses():
                log.info("USD: %s", _one_line(st.commentary))
            trap.ClearWarnings()
            trap.ClearStatuses()


def check_up_axis(stage: Usd.Stage, where) -> None:
    """Refuse an authored upAxis other than "Y" or "Z" (USD allows no other) before anything uses it."""
    if stage.HasAuthoredMetadata("upAxis"):
        up = str(stage.GetMetadata("upAxis"))
        if up not in ("Y", "Z"):
            raise LfusdError(f"stage {where} has upAxis {up!r}, which USD does not allow; set upAxis to \"Z\" or \"Y\" in its "
                             "layer metadata (re-export a .usdz)")


def composition_problem(stage: Usd.Stage, where) -> str | None:
    """One line on what keeps a stage from composing (a reference, payload or sublayer that cannot
    be opened, a sublayer cycle, ...: ``Usd.Stage.GetCompositionErrors``, what `lfusd check` lists),
    or None when it composes."""
    errors = stage.GetCompositionErrors()
    if not errors:
        return None
    first = _one_line(str(errors[0])).rstrip(".")
    more = f" (and {len(errors) - 1} more: `lfusd check {where}` lists them)" if len(errors) > 1 else ""
    return (f"stage {where} does not compose: {first}{more}; what it names is not in the render: fix or remove that "
            "reference or sublayer, then render again")


def open_stage(path: str | Path, warn: bool = True, render: bool = False) -> Usd.Stage:
    """Open a USD stage, or raise LfusdError naming the file and what is wrong with it. pxr's
    warnings while composing it come out as one line each (:func:`usd_warnings`; none when
    ``warn`` is False); for a ``render``, its composition errors come out as one line saying what
    they mean (:func:`composition_problem`)."""
    p = Path(path)
    if not p.exists():
        raise LfusdError(f"stage {p} does not exist; give the path of a .usda/.usdc/.usdz/.usd file")
    if p.is_dir():
        raise LfusdError(f"stage {p} is a folder; give the path of a .usda/.usdc/.usdz/.usd file")
    try:
        with usd_warnings(report=warn, composition=not render):
            stage = Usd.Stage.Open(str(p))
    except Tf.ErrorException as e:
        first = str(e).strip().splitlines()
        reason = next((ln.strip() for ln in first if ln.strip().startswith(("Error", "Failed", "syntax", "unexpected"))), "")
        raise LfusdError(f"stage {p} is not a readable USD file ({reason or 'parse error'}); fix or regenerate it") from None
    if stage is None:
        raise LfusdError(f"stage {p} is not a readable USD file; fix or regenerate it")
    check_up_axis(stage, p)
    problem = composition_problem(stage, p) if render else None
    if problem:
        log.warning("%s", problem)
    return stage


# Stage metadata a stage reads from its root layer only (a sublayer's is ignored): a layer over an
# asset copies them so that the composed stage keeps the asset's axes, units, timing and default
# prim. timeCodesPerSecond matters for composition too: a sublayer whose rate differs from its
# parent's is time-scaled.
LAYER_METADATA = ("upAxis", "metersPerUnit", "timeCodesPerSecond", "framesPerSecond", "startTimeCode", "endTimeCode", "defaultPrim")
WRITABLE_SUFFIXES = (".usda", ".usdc", ".usd")


def _sublayer_path(asset: Path, layer_path: Path) -> str:
    """``asset`` as the layer at ``layer_path`` should name it: relative to its folder when possible."""
    try:
        rel = os.path.relpath(asset.resolve(), layer_path.resolve().parent)
    except ValueError:  # another drive (Windows): no relative path exists
        return asset.resolve().as_posix()
    rel = Path(rel).as_posix()
    return rel if rel.startswith("../") else f"./{rel}"


def layer_over(asset: str | Path, out: str | Path) -> Usd.Stage:
    """A stage whose root layer, to be saved as the new file ``out``, sublayers ``asset``
    (unchanged) and carries its root layer's metadata (:data:`LAYER_METADATA`); what lfusd
    authors then goes into ``out``. Nothing is written until the caller saves the root layer."""
    asset_path, out_path = Path(asset), Path(out)
    # held: its root layer lives as long as the stage; quiet: the stage over it composes the same
    # arcs and reports each broken one (else every warning came twice)
    asset_stage = open_stage(asset_path, warn=False)
    base = asset_stage.GetRootLayer().pseudoRoot
    if out_path.exists():
        raise LfusdError(f"{out_path} already exists; edit it in place by dropping -o, or give -o a new file")
    if out_path.suffix.lower() not in WRITABLE_SUFFIXES:
        raise LfusdError(f"-o {out_path} is not a {'/'.join(WRITABLE_SUFFIXES)} file; give -o a new layer such as scene.usda")
    if not out_path.resolve().parent.is_dir():
        raise LfusdError(f"folder {out_path.parent} of -o {out_path} does not exist; create it or give another -o")
    fmt = Sdf.FileFormat.FindByExtension(out_path.suffix.lstrip(".").lower())
    layer = Sdf.Layer.New(fmt, str(out_path.resolve()))  # New, unlike CreateNew, writes nothing yet
    for key in LAYER_METADATA:
        if base.HasInfo(key):
            layer.pseudoRoot.SetInfo(key, base.GetInfo(key))
    layer.subLayerPaths.append(_sublayer_path(asset_path, out_path))
    with usd_warnings():
        return Usd.Stage.Open(layer)


def open_for_edit(path: str | Path, out: str | Path | None = None) -> Usd.Stage:
    """The stage lfusd's authoring commands write into and save: with ``out``, a new layer over
    ``path`` (:func:`layer_over`); without, ``path`` itself, refused in one line when it cannot
    be written (a .usdz package, a read-only file)."""
    if out is not None:
        return layer_over(path, out)
    stage = open_stage(path)
    layer = stage.GetRootLayer()
    if layer.GetFileFormat().IsPackage():
        why = f"a .{Path(layer.realPath).suffix.lstrip('.')} package is read-only"
    elif not (layer.permissionToEdit and layer.permissionToSave and os.access(layer.realPath, os.W_OK)):
        why = "the file is read-only"
    else:
        return stage
    raise LfusdError(f"cannot write into {path} ({why}); author in a new layer over it with -o scene.usda")


def save_stage(stage: Usd.Stage, target: str | Path) -> None:
    """Save the root layer that :func:`open_for_edit` opened (``target``: the file it writes, for
    the message); a failure is one line naming the file."""
    try:
        stage.GetRootLayer().Save()
    except Exception as e:  # pxr reports an unwritable layer as Tf.ErrorException
        raise LfusdError(f"cannot save stage {Path(target)} ({(str(e).strip().splitlines() or [type(e).__name__])[-1]}); check the file is writable") from None


def frame_range(stage: Usd.Stage) -> tuple[int, int]:
    """(first, last) frame, inclusive; a stage with no authored time range is one static frame, 1."""
    if not stage.HasAuthoredTimeCodeRange():
        return 1, 1
    return int(round(stage.GetStartTimeCode())), int(round(stage.GetEndTimeCode()))


def is_static(stage: Usd.Stage) -> bool:
    """True when nothing on the stage can change over time: no layer it uses (sublayers,
    references, loaded payloads, value clips) holds a time sample.

    Asks each layer for its samples (``Sdf.Layer.ListAllTimeSamples``, about 1 ms on a 20,000-
    attribute stage) instead of every composed attribute (``ValueMightBeTimeVarying`` over a
    traversal, 30 ms there). It errs towards animated: a sample hidden by a stronger default
    counts. Spline-valued attributes (``Usd.Attribute.HasSpline``) are not looked for."""
    return not any(layer.ListAllTimeSamples() for layer in stage.GetUsedLayers())


def check_frames(stage: Usd.Stage, frames: list[int], stage_path: str | Path) -> None:
    """Raise LfusdError when any frame lies outside an animated stage's range; a static stage
    (:func:`is_static`) is the same at every time code, so any frame is in it."""
    if is_static(stage):
        return
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


def _identity_key(path: Path, root: Path) -> str:
    """A dependency's name in the identity: relative to the stage's folder when inside it, so
    that moving a project folder keeps its datasets' identity."""
    try:
        return path.relative_to(root).as_posix()
    except ValueError:
        return path.as_posix()


# The first bytes of the files a stage may use from outside its folder: images (textures, HDRIs)
# and USD layers. Anything else named there (a texture path leading to /etc/shadow) is not read.
_MAGIC = (b"\x89PNG\r\n\x1a\n", b"\xff\xd8\xff", b"\x76\x2f\x31\x01", b"II*\x00", b"MM\x00*", b"#?RADIANCE", b"#?RGBE",
          b"BM", b"DDS ", b"\xabKTX", b"GIF8", b"PXR-USDC", b"#usda", b"PK\x03\x04")


def _image_or_layer(path: Path) -> bool:
    """Whether the file at ``path`` starts like an image or a USD layer (:data:`_MAGIC`; WebP by its RIFF header)."""
    try:
        with open(path, "rb") as f:
            head = f.read(16)
    except OSError:
        return False
    return head.startswith(_MAGIC) or (head[:4] == b"RIFF" and head[8:12] == b"WEBP")


def _stat_key(st: os.stat_result) -> dict:
    """What decides that a file is unchanged without reading it: size, mtime, ctime and inode
    together. Restoring an mtime (touch -r, cp -p, rsync -a, tar x) changes the ctime (and a copy
    the inode), so an edit that keeps the size and mtime is still hashed again."""
    return {"size": st.st_size, "mtime_ns": st.st_mtime_ns, "ctime_ns": st.st_ctime_ns, "inode": st.st_ino}


def _package(path: str) -> str:
    """A file inside a .usdz package (``pkg.usdz[inner/file.png]``) is read from the package,
    whose hash covers it: the package's path; any other path as it is."""
    return path.split("[", 1)[0] if path.endswith("]") and "[" in path else path


def stage_files(path: str | Path, known: dict | None = None) -> dict[str, dict]:
    """Every file that affects a render of the stage at ``path``: its layer stack (sublayers,
    references, payloads) and the assets its layers name (textures, ...), as
    ``{name: {"size", "mtime_ns", "ctime_ns", "inode", "sha256"}}``; a named asset that does not
    resolve is ``{"missing": True}``. An asset outside the stage's folder tree (after resolving
    links) is read and recorded only when it is an image or a USD layer (:func:`_image_or_layer`);
    anything else is left out with a warning. ``known``: a previous result whose hashes are reused
    for files whose size, mtime, ctime and inode are all unchanged (hashing every texture on
    every run is the cost it saves)."""
    stage_path = Path(path).resolve()
    root = stage_path.parent
    try:
        layers, assets, unresolved = UsdUtils.ComputeAllDependencies(str(stage_path))
    except Tf.ErrorException as e:
        reason = next((ln.strip() for ln in str(e).splitlines() if ln.strip()), "a layer failed to load")[:200]
        raise LfusdError(f"cannot resolve the files stage {path} depends on ({reason}); fix its references") from None
    layer_paths = {Path(_package(layer.realPath)).resolve() for layer in layers if layer.realPath} | {stage_path}
    asset_paths = {Path(_package(a)).resolve() for a in assets} - layer_paths
    outside = sorted(p for p in asset_paths if not p.is_relative_to(root) and not _image_or_layer(p))
    for p in outside:
        log.warning("stage %s names %s, outside its folder and neither an image nor a USD layer: "
                                            "not read, not part of the dataset's identity", path, p)
    paths = layer_paths | (asset_paths - set(outside))
    known = known or {}
    files: dict[str, dict] = {}
    for p in sorted(paths):
        key = _identity_key(p, root)
        try:
            st = p.stat()
        except OSError:
            files[key] = {"missing": True}
            continue
        old = known.get(key) or {}
        now = _stat_key(st)
        if old.get("sha256") and all(old.get(k) == v for k, v in now.items()):
            files[key] = dict(old)
        else:
            try:
                files[key] = {**now, "sha256": file_hash(p)}
            except OSError as e:
                raise LfusdError(f"cannot read {p}, a file stage {path} depends on ({e.strerror}); fix its permissions") from None
    for u in unresolved:
        files.setdefault(_identity_key(Path(u), root), {"missing": True})
    return files


def files_digest(files: dict[str, dict]) -> str:
    """One sha256 over the names and contents of ``files`` (a :func:`stage_files` result)."""
    h = hashlib.sha256()
    for key in sorted(files):
        h.update(f"{key}\0{files[key].get('sha256', 'missing')}\n".encode())
    return h.hexdigest()


def changed_file(old: dict[str, dict], new: dict[str, dict]) -> str | None:
    """The first file whose content differs between two :func:`stage_files` results (or that one
    of them lacks), or None."""
    for key in sorted(set(old) | set(new)):
        if (old.get(key) or {}).get("sha256") != (new.get(key) or {}).get("sha256"):
            return key
    return None


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


# Y-up stage -> Z-up world: +90 degrees about X, (x, y, z) -> (x, -z, y).
_Y_UP_TO_Z_UP = np.array([[1.0, 0.0, 0.0], [0.0, 0.0, -1.0], [0.0, 1.0, 0.0]])


@dataclass(frozen=True)
class WorldFrame:
    """How a stage's coordinates map into lfusd's world (Z-up, metres; docs/CONVENTIONS.md):
    rotate the stage's up axis onto +Z, then scale by metersPerUnit. The one owner of that map:
    camera poses, object poses and geometry all go through it."""

    up_axis: str
    meters_per_unit: float

    @property
    def rotation(self) -> np.ndarray:
        """3x3 rotation from the stage's axes to the world's."""
        return _Y_UP_TO_Z_UP.copy() if self.up_axis == "Y" else np.eye(3)

    def matrix(self) -> np.ndarray:
        """4x4 map of stage points (scene units) to world points (metres)."""
        m = np.eye(4)
        m[:3, :3] = self.rotation * self.meters_per_unit
        return m

    def points(self, points: np.ndarray) -> np.ndarray:
        """(N,3) stage points in scene units -> world points in metres."""
        return (np.asarray(points, np.float64) @ self.rotation.T) * self.meters_per_unit

    def stage_points(self, points: np.ndarray) -> np.ndarray:
        """(N,3) world points in metres -> stage points in scene units (the inverse of :meth:`points`)."""
        return (np.asarray(points, np.float64) / self.meters_per_unit) @ self.rotation

    def pose(self, usd_matrix) -> np.ndarray:
        """A USD local-to-world matrix (row vectors, scene units) as a 4x4 column-vector world
        pose whose translation is in metres (its linear part keeps any authored scale)."""
        m = np.array(usd_matrix, dtype=np.float64).T
        out = np.eye(4)
        out[:3, :3] = self.rotation @ m[:3, :3]
        out[:3, 3] = self.rotation @ m[:3, 3] * self.meters_per_unit
        return out

    def to_dict(self) -> dict:
        """What the manifest records: the stage's up axis, units and the applied 4x4 map."""
        return {"up_axis": self.up_axis, "meters_per_unit": self.meters_per_unit, "stage_to_world": self.matrix().tolist()}


def world_frame(stage: Usd.Stage) -> WorldFrame:
    """The stage's :class:`WorldFrame` (its upAxis and metersPerUnit, USD's defaults where unauthored)."""
    check_up_axis(stage, stage.GetRootLayer().identifier)
    return WorldFrame(str(UsdGeom.GetStageUpAxis(stage)), meters_per_unit(stage))


#: Decimal places to which generated stages store every floating-point value: 1e-9 of a unit
#: (1 nm on lfusd's metre stages; 1e-9 of a rotation-matrix entry, a UV or a degree).
STAGE_DECIMALS = 9

# Floating-point scalar types, by their C++ name (scalar and array forms share it).
_FLOAT_TYPES = {
    f"{base}{suffix}"
    for suffix in ("d", "f", "h")
    for base in ("GfVec2", "GfVec3", "GfVec4", "GfMatrix2", "GfMatrix3", "GfMatrix4", "GfQuat")
    if not (base.startswith("GfMatrix") and suffix != "d")
} | {"double", "float", "GfHalf"}


def round_values(values, decimals: int = STAGE_DECIMALS) -> np.ndarray:
    """``values`` as float64 rounded to ``decimals`` places, with -0 written as 0.

    NumPy, BLAS and libm results differ in the last bit between CPUs (SIMD paths, FMA), and
    cancellations leave CPU-dependent residues such as 1e-17 where the value is 0; rounded to a
    grid far coarser than both, a generator's values are portable (a value changes only if it
    lies within one ulp of a grid midpoint)."""
    return np.round(np.asarray(values, np.float64), decimals) + 0.0


def _quat(q, cls):
    return cls(float(q[0]), *(float(v) for v in q[1:]))


def typed_value(arr: np.ndarray, type_name: Sdf.ValueTypeName, like=None):
    """The USD value of ``type_name`` holding ``arr`` (not quaternions); ``like``: an array value
    whose element type the result keeps (float32 points stay float32)."""
    cls = type_name.type.pythonClass
    if cls is None:  # double, float, half: a Python float
        return float(arr)
    if type_name.isArray:
        return cls.FromNumpy(arr if like is None else arr.astype(np.array(like).dtype))
    return cls(arr.tolist()) if arr.ndim == 2 else cls(*arr.tolist())


def _rounded(value, type_name: Sdf.ValueTypeName, decimals: int):
    if "Quat" in type_name.scalarType.cppTypeName:
        quat = getattr(Gf, type_name.scalarType.cppTypeName[2:])
        quats = value if type_name.isArray else [value]
        rounded = [_quat(round_values([q.GetReal(), *q.GetImaginary()], decimals), quat) for q in quats]
        return type_name.type.pythonClass(rounded) if type_name.isArray else rounded[0]
    return typed_value(round_values(value if isinstance(value, float) else np.array(value), decimals), type_name, like=value)


def float_attribute_specs(layer: Sdf.Layer) -> list[Sdf.AttributeSpec]:
    """Every attribute spec of ``layer`` whose values are floating point (double, float, half)."""
    specs: list[Sdf.AttributeSpec] = []

    def visit(path: Sdf.Path) -> None:
        spec = layer.GetObjectAtPath(path)
        if isinstance(spec, Sdf.AttributeSpec) and spec.typeName.scalarType.cppTypeName in _FLOAT_TYPES:
            specs.append(spec)

    layer.Traverse(Sdf.Path.absoluteRootPath, visit)
    return specs


def round_layer(layer: Sdf.Layer, decimals: int = STAGE_DECIMALS) -> int:
    """Round every floating-point attribute value of ``layer`` (defaults and time samples) to
    ``decimals`` places, so that one seed writes the same bytes on every CPU; returns the
    number of values rounded. Float and half values are rounded in float64, then stored in
    their own precision (for a float above ~0.02 its own step is coarser than the grid)."""
    count = 0
    # Values are cleared before they are set: Sdf ignores a set to an equal value, and -0 == 0.
    for spec in float_attribute_specs(layer):
        if spec.HasDefaultValue() and spec.default is not None:
            value = _rounded(spec.default, spec.typeName, decimals)
            spec.ClearDefaultValue()
            spec.default = value
            count += 1
        for t in layer.ListTimeSamplesForPath(spec.path):
            value = _rounded(layer.QueryTimeSample(spec.path, t), spec.typeName, decimals)
            layer.EraseTimeSample(spec.path, t)
            layer.SetTimeSample(spec.path, t, value)
            count += 1
    return count

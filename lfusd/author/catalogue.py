"""The asset catalogue: USD assets that scene templates draw by semantic class.

A catalogue is one JSON file the user names (``catalogue.json`` beside the assets by default;
``lfusd assets add|list|check``). Each entry records what lfusd needs to place the asset in a
generated stage with the one world frame (docs/CONVENTIONS.md) and what makes it trustworthy:
its file (relative to the catalogue's folder when inside it), default prim, class (one of
lfusd.author.vocabulary.OBJECTS), world bounds in metres (Z up, the asset's own placement), units
(metersPerUnit), up axis, ground contact (the lowest point's height, metres), licence, the
number of triangles and textured materials, and a content hash over the asset's files (its layer
stack and the textures it names: lfusd.author.stage.stage_files).

lfusd's own procedural generators are catalogue entries too (:data:`PROCEDURAL`, source
``procedural``): a template draws a class from the catalogues' assets of that class when any
are given, and from its procedural generator otherwise (:func:`draw_assets`).

An asset is refused, in one line, when it is not a mesh asset (no drawn geometry), has no class
(no UsdSemantics ``class`` label in the vocabulary and no ``--class``), empty bounds, implicit
shapes, faces out of range or non-finite points (lfusd.author.geometry's checks), a light inside
an instance, or files it names that do not resolve. Its other lights are recorded and switched
off where it is placed (the templates light their scenes).
"""

from __future__ import annotations

import json
import logging
import math
import os
from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np

from ..errors import LfusdError
from ..files import atomic_write
from .vocabulary import LICENCE, OBJECTS

log = logging.getLogger(__name__)

CATALOGUE_NAME = "catalogue.json"  # the default catalogue file, beside the assets
FORMAT = "lfusd-catalogue"
VERSION = 1
USD_SUFFIXES = (".usd", ".usda", ".usdc", ".usdz")

# Metadata keys read as an asset's licence (the layer's customLayerData, then the default
# prim's assetInfo / customData), first found wins.
LICENCE_KEYS = ("license", "licence", "License", "Licence", LICENCE, "copyright")

# lfusd's procedural generators, registered as catalogue entries (lfusd.author.scenes.objects):
# class -> generator. A template that finds no catalogue asset of a class uses its generator.
PROCEDURAL = {
    "person": "objects.person", "car": "objects.car", "tree": "objects.tree", "bench": "objects.bench",
    "bin": "objects.litter_bin", "chair": "objects.chair", "table": "objects.table", "shelf": "objects.shelf",
    "cabinet": "objects.cabinet", "building": "objects.building", "boat": "objects.boat",
    "street_light": "objects.street_light", "lamp": "objects.floor_lamp", "bowl": "objects.bowl_kit",
    "railing": "objects.railing",
}
# The classes that templates draw from catalogues (the others keep their procedural generator:
# their templates need more than a box, e.g. a boat's draft or a street light's lamp).
DRAWN = ("person", "car", "tree", "bench", "bin", "chair", "table", "shelf")


@dataclass(frozen=True)
class Asset:
    """One catalogue entry (see the module docstring); ``file`` is as stored (relative to the
    catalogue's folder when inside it), :meth:`path` resolves it."""

    name: str
    file: str
    prim: str
    cls: str
    bounds: tuple[tuple[float, float, float], tuple[float, float, float]]
    meters_per_unit: float
    up_axis: str
    ground: float
    licence: str
    sha256: str
    triangles: int
    textured_materials: int
    lights: tuple[str, ...] = ()  # the asset's lights, relative to its prim: switched off where it is placed
    folder: str = ""  # the catalogue's folder (not stored)

    def path(self) -> Path:
        p = Path(self.file)
        return p if p.is_absolute() else Path(self.folder) / p

    def to_json(self) -> dict:
        d = asdict(self)
        d.pop("folder")
        d["class"] = d.pop("cls")
        d["bounds"] = [list(c) for c in self.bounds]
        d["lights"] = list(self.lights)
        return d

    @classmethod
    def from_json(cls, d: dict, folder: Path) -> Asset:
        """The entry ``d`` of a catalogue in ``folder``, its fields checked (:func:`_check_entry`):
        ValueError naming the first that is not what `lfusd assets add` writes."""
        d = dict(d)
        d["cls"] = d.pop("class")
        d["bounds"] = tuple(tuple(float(v) for v in c) for c in d["bounds"])
        d["lights"] = tuple(d.get("lights", ()))
        _check_entry(d)
        return cls(**d, folder=str(folder))


def _check_entry(d: dict) -> None:
    """An entry's fields as `lfusd assets add` writes them: a plain name, a file, an absolute prim
    path, lights as prim paths below it (never ``..``), bounds of two finite 3-vectors lo <= hi, a
    positive scale and a Y or Z up axis; ValueError naming the first field that is not."""
    from pxr import Sdf

    name = d.get("name")
    if not (isinstance(name, str) and 0 < len(name) <= 255 and name.isprintable() and "/" not in name and "\\" not in name
            and not name.startswith(".")):
        raise ValueError(f"name {str(name)[:60]!r} is not an asset name (printable, no path separator, not hidden)")
    where = f"asset {name!r}"
    if not isinstance(d.get("file"), str) or not d["file"] or not d["file"].isprintable():
        raise ValueError(f"{where}: 'file' is not a file name")
    prim = d.get("prim")
    if not (isinstance(prim, str) and Sdf.Path.IsValidPathString(prim) and Sdf.Path(prim).IsAbsolutePath()
            and Sdf.Path(prim).IsPrimPath()):
        raise ValueError(f"{where}: prim {str(prim)[:60]!r} is not an absolute prim path")
    for light in d["lights"]:
        ok = isinstance(light, str) and Sdf.Path.IsValidPathString(light)
        p = Sdf.Path(light) if ok else None
        if not (ok and not p.IsAbsolutePath() and p.IsPrimPath() and ".." not in light.split("/") and light not in (".", "")):
            raise ValueError(f"{where}: light {str(light)[:60]!r} is not a prim path below the asset's prim")
    lo, hi = d["bounds"] if len(d["bounds"]) == 2 else ((), ())
    if not (len(lo) == 3 and len(hi) == 3 and all(np.isfinite(lo)) and all(np.isfinite(hi)) and all(a <= b for a, b in zip(lo, hi))):
        raise ValueError(f"{where}: 'bounds' is not two finite 3-vectors, low then high")
    mpu = d.get("meters_per_unit")
    if isinstance(mpu, bool) or not isinstance(mpu, (int, float)) or not (math.isfinite(mpu) and mpu > 0):
        raise ValueError(f"{where}: 'meters_per_unit' is not a positive number")
    if d.get("up_axis") not in ("Y", "Z"):
        raise ValueError(f"{where}: 'up_axis' is not Y or Z")


# -- reading an asset -----------------------------------------------------------------------------

def _licence(stage, prim) -> str:
    """The licence named in the asset's metadata ('' when none)."""
    sources = [stage.GetRootLayer().customLayerData or {}]
    if prim:
        sources += [prim.GetAssetInfo() or {}, prim.GetCustomData() or {}]
    for src in sources:
        for key in LICENCE_KEYS:
            if isinstance(src.get(key), str) and src[key].strip():
                return src[key].strip()
    return ""


def _asset_class(stage, prim, file: Path, given: str | None) -> str:
    """The asset's class: ``given``, else its default prim's class label, else the one class
    that its labelled prims carry; refused when none, several, or one outside the vocabulary."""
    from pxr import Usd

    from .labels import class_labels

    if given:
        if given not in OBJECTS:
            raise LfusdError(f"--class {given!r} is not an object class lfusd knows; use one of {', '.join(OBJECTS)}")
        return given
    found = class_labels(prim)
    if not found:
        seen: list[str] = []
        for p in Usd.PrimRange(prim, Usd.TraverseInstanceProxies(Usd.PrimDefaultPredicate)):
            seen += [c for c in class_labels(p) if c not in seen]
        found = seen
    known = [c for c in found if c in OBJECTS]
    if not found:
        raise LfusdError(f"asset {file} has no class (no UsdSemantics 'class' label on its prims); "
                         "label its default prim or pass --class CLASS")
    if not known:
        raise LfusdError(f"asset {file} is labelled {', '.join(found)}, not an object class lfusd knows; "
                         f"pass --class with one of {', '.join(OBJECTS)}")
    if len(set(known)) > 1:
        raise LfusdError(f"asset {file} carries several classes ({', '.join(known)}); pass --class CLASS to say which it is")
    return known[0]


def inspect_asset(file: str | Path, cls: str | None = None, licence: str | None = None, name: str | None = None) -> Asset:
    """Read, check and describe the asset at ``file`` (a .usd/.usda/.usdc/.usdz file); LfusdError
    in one line when it is refused (see the module docstring)."""
    from pxr import Sdf, Tf, Usd, UsdLux

    from .geometry import StageGeometry, check_geometry
    from .stage import files_digest, usd_warnings

    file = Path(file)
    if file.suffix.lower() not in USD_SUFFIXES:
        raise LfusdError(f"{file} is not a USD file; give a .usd, .usda, .usdc or .usdz asset")
    try:
        with usd_warnings():
            stage = Usd.Stage.Open(str(file))
    except Tf.ErrorException:  # an unreadable layer (pxr's message is a multi-line C++ trace)
        raise LfusdError(f"cannot open asset {file}: USD cannot read it (not a USD layer, or damaged); "
                         "give a readable USD file") from None
    if stage is None:
        raise LfusdError(f"cannot open asset {file}; give a readable USD file")
    prim = stage.GetDefaultPrim()
    if not prim:
        roots = [p for p in stage.GetPseudoRoot().GetChildren() if p.IsDefined() and not p.IsAbstract()]
        if len(roots) != 1:
            raise LfusdError(f"asset {file} has no defaultPrim and {len(roots)} root prims; set its defaultPrim to the asset's root")
        prim = roots[0]
    # Lights (glTF converters bring the exporter's): switched off where the asset is placed, as the
    # template lights its scene; one inside an instance cannot be, so the asset is refused.
    lights = [p for p in Usd.PrimRange(prim, Usd.TraverseInstanceProxies(Usd.PrimDefaultPredicate))
              if p.HasAPI(UsdLux.LightAPI) or p.IsA(UsdLux.BoundableLightBase) or p.IsA(UsdLux.NonboundableLightBase)]
    inside = [p for p in lights if p.IsInstanceProxy()]
    if inside:
        raise LfusdError(f"asset {file} has a light inside an instance ({inside[0].GetPath()}), which lfusd cannot switch "
                         "off; remove the asset's lights")
    if prim.HasAPI(UsdLux.LightAPI) or any(p.GetPath() == prim.GetPath() for p in lights):
        raise LfusdError(f"asset {file}'s root prim {prim.GetPath()} is a light; give an asset with geometry")
    if lights:
        log.warning("asset %s has %d light%s (%s): switched off where it is placed (templates light their scenes)",
                    file, len(lights), "s" if len(lights) > 1 else "", lights[0].GetPath())
    try:
        geometry = StageGeometry(stage)
        check_geometry(geometry)
    except LfusdError as e:
        raise LfusdError(f"asset {file}: {e}") from None
    root = prim.GetPath()
    parts = [p for p in geometry.parts if Sdf.Path(p.path.split("[")[0]).HasPrefix(root)]
    if not parts:
        raise LfusdError(f"asset {file} is not a mesh asset (no drawn Mesh under {prim.GetPath()}); give a USD file with geometry")
    cls = _asset_class(stage, prim, file, cls)
    t = stage.GetStartTimeCode() if stage.HasAuthoredTimeCodeRange() else 0.0
    verts, triangles = [], 0
    for part in parts:
        m = geometry.mesh(part, t)
        verts.append(m.vertices)
        triangles += len(m.triangles)
    pts = np.concatenate(verts) if verts else np.zeros((0, 3))
    lo, hi = (pts.min(0), pts.max(0)) if len(pts) else (np.zeros(3), np.zeros(3))
    if not len(pts) or np.sum(hi - lo > 1e-6) < 2:  # a point or a line; a flat asset (a rug, a sign) is fine
        raise LfusdError(f"asset {file} has empty bounds ({np.round(lo, 6).tolist()} to {np.round(hi, 6).tolist()} m); "
                         "give an asset with extent on at least two axes")
    files = content_files(file)
    missing = sorted(k for k, v in files.items() if v.get("missing"))
    if missing:
        raise LfusdError(f"asset {file} names {missing[0]}, which does not exist; put the file beside the asset or fix the path")
    from .rules import usd_validation
    from .statistics import textured_materials

    issues = usd_validation(stage)
    if issues:  # the asset is usable; the scenes that draw it will be reported by `lfusd check`
        log.warning("asset %s fails USD validation (%s%s): `lfusd check` reports it in every scene that draws it; "
                    "fix the asset, or check those scenes with --no-usd-validation", file, issues[0],
                    f"; and {len(issues) - 1} more" if len(issues) > 1 else "")

    odd = implausible_size(cls, (lo, hi), geometry.frame.meters_per_unit)
    if odd:  # added all the same (the user may mean it), but said: the scenes would not fit it
        log.warning("asset %s: %s", file, odd)
    return Asset(name=name or file.stem, file=str(file), prim=str(prim.GetPath()), cls=cls,
                 bounds=(tuple(round(float(v), 6) for v in lo), tuple(round(float(v), 6) for v in hi)),
                 meters_per_unit=geometry.frame.meters_per_unit, up_axis=geometry.frame.up_axis,
                 ground=round(float(lo[2]), 6), licence=(licence or _licence(stage, prim)), sha256=files_digest(files),
                 triangles=int(triangles), textured_materials=textured_materials(stage),
                 lights=tuple(str(p.GetPath().MakeRelativePath(prim.GetPath())) for p in lights))


def implausible_size(cls: str, bounds, meters_per_unit: float = 1.0) -> str | None:
    """What is wrong with an asset of class ``cls`` whose bounds (metres) are outside the class's
    plausible size (:data:`lfusd.author.vocabulary.PLAUSIBLE_SIZE`), with the metersPerUnit that
    would make it plausible when a unit mix-up explains it; None when plausible or unknown."""
    from .vocabulary import PLAUSIBLE_SIZE

    if cls not in PLAUSIBLE_SIZE:
        return None
    least, most = PLAUSIBLE_SIZE[cls]
    size = float(np.max(np.asarray(bounds[1], float) - np.asarray(bounds[0], float)))
    if least <= size <= most:
        return None
    hint = "check its metersPerUnit and scale"
    for factor in (100.0, 1000.0, 1 / 100.0, 1 / 1000.0, 1 / 0.0254):  # cm, mm, m read as cm / mm, inches
        if least <= size / factor <= most:
            hint = (f"its geometry looks {factor:g} times too {'large' if factor > 1 else 'small'}: "
                    f"set metersPerUnit = {meters_per_unit / factor:g} in the asset, then add it again")
            break
    return (f"a {size:.3g} m {cls} is implausible (a {cls}'s longest side is {least:g}-{most:g} m), "
            f"so no scene will have room for it; {hint}")


def content_files(file: str | Path) -> dict[str, dict]:
    """The files an asset's content hash covers (lfusd.author.stage.stage_files: its layers and
    the textures they name; a .usdz package as one file)."""
    from .stage import stage_files

    return stage_files(file)


# -- the catalogue file ---------------------------------------------------------------------------

def catalogue_path(target: str | Path, catalogue: str | Path | None = None) -> Path:
    """The catalogue file for assets at ``target``: ``catalogue`` (a file, or a folder that gets
    :data:`CATALOGUE_NAME`), else ``catalogue.json`` in the folder ``target`` is or is in."""
    if catalogue is not None:
        c = Path(catalogue)
        return c / CATALOGUE_NAME if c.is_dir() else c
    t = Path(target)
    return (t if t.is_dir() else t.parent) / CATALOGUE_NAME


def load_catalogue(path: str | Path) -> list[Asset]:
    """The entries of the catalogue file at ``path`` (a folder: its catalogue.json)."""
    path = Path(path)
    if path.is_dir():
        path = path / CATALOGUE_NAME
    try:
        data = json.loads(path.read_text())
    except FileNotFoundError:
        raise LfusdError(f"catalogue {path} does not exist; make it with `lfusd assets add FOLDER`") from None
    except (OSError, ValueError) as e:
        raise LfusdError(f"cannot read catalogue {path} ({getattr(e, 'strerror', None) or e}); give an lfusd catalogue file") from None
    if not (isinstance(data, dict) and data.get("format") == FORMAT and isinstance(data.get("assets"), list)):
        raise LfusdError(f"{path} is not an lfusd catalogue; give a file written by `lfusd assets add`")
    if data.get("version") != VERSION:
        raise LfusdError(f"catalogue {path} has version {data.get('version')!r}, this lfusd reads {VERSION}; "
                         "make it again with `lfusd assets add`")
    try:
        return [Asset.from_json(d, path.parent) for d in data["assets"]]
    except (KeyError, TypeError, ValueError) as e:
        raise LfusdError(f"catalogue {path} has a damaged entry ({e}); make it again with `lfusd assets add`") from None


def _write_catalogue(path: Path, assets: list[Asset]) -> None:
    if path.is_symlink():
        raise LfusdError(f"catalogue {path} is a symbolic link; lfusd writes catalogues only as plain files: "
                         "remove the link or pass another --catalogue")
    body = {"format": FORMAT, "version": VERSION, "assets": [a.to_json() for a in sorted(assets, key=lambda a: a.name)]}
    # written beside itself under a temporary name, then renamed into place (replacing a link's
    # target is impossible by construction: the rename replaces the directory entry)
    atomic_write(path, json.dumps(body, indent=1) + "\n")


def _stored_file(file: Path, folder: Path) -> str:
    """How the catalogue stores an asset's file: relative to its folder when inside it."""
    file = file.resolve()
    try:
        return file.relative_to(folder.resolve()).as_posix()
    except ValueError:
        return str(file)


def asset_files(target: str | Path) -> list[Path]:
    """The USD assets at ``target``: the file itself, or a folder's USD files (recursively) that
    no other USD file there uses as a layer (sublayers, references and payloads are parts of
    the assets that use them, not assets of their own)."""
    target = Path(target)
    if not target.exists():
        raise LfusdError(f"{target} does not exist; give a USD asset file or a folder of them")
    if target.is_file():
        return [target]
    files = sorted(p for p in target.rglob("*") if p.is_file() and p.suffix.lower() in USD_SUFFIXES)
    if not files:
        raise LfusdError(f"folder {target} holds no USD files (.usd, .usda, .usdc, .usdz); give a folder of assets")
    from pxr import Sdf

    used: set[Path] = set()
    for f in files:
        if f.suffix.lower() == ".usdz":
            continue
        layer = Sdf.Layer.FindOrOpen(str(f))
        if layer is None:
            continue
        for ref in layer.GetCompositionAssetDependencies():
            p = (f.parent / ref).resolve() if not os.path.isabs(ref) else Path(ref).resolve()
            if p != f.resolve():
                used.add(p)
    return [f for f in files if f.resolve() not in used]


def add_assets(target: str | Path, catalogue: str | Path | None = None, cls: str | None = None,
               licence: str | None = None) -> tuple[Path, list[Asset]]:
    """Inspect the assets at ``target`` and add them to the catalogue (made when missing):
    ``(catalogue file, the added entries)``. Nothing is written unless every asset passes; an
    asset already in the catalogue (same file) is replaced by its new reading."""
    path = catalogue_path(target, catalogue)
    if path.exists() and not path.is_file():
        raise LfusdError(f"catalogue {path} is not a file; pass --catalogue with a .json file")
    if path.suffix.lower() != ".json":
        raise LfusdError(f"catalogue {path} must be a .json file; pass --catalogue FILE.json")
    if not path.parent.is_dir():
        raise LfusdError(f"folder {path.parent} of catalogue {path} does not exist; create it or pass another --catalogue")
    old = load_catalogue(path) if path.exists() else []
    folder = path.parent
    files = asset_files(target)
    new = []
    for f in files:
        stored = _stored_file(f, folder)
        a = inspect_asset(f, cls, licence)
        new.append(Asset(**{**asdict(a), "file": stored, "folder": str(folder)}))
    replaced = {a.file for a in new}
    kept = [a for a in old if a.file not in replaced]
    taken = {a.name for a in kept}
    named = []
    for a in new:
        base, name, k = a.name, a.name, 2
        while name in taken:
            name, k = f"{base}_{k}", k + 1
        taken.add(name)
        named.append(Asset(**{**asdict(a), "name": name}))
    _write_catalogue(path, kept + named)
    return path, named


def check_catalogue(path: str | Path) -> list[str]:
    """Read every asset of the catalogue again: one line per asset that is missing, refused, or
    changed since it was added (content hash or recorded description); [] when all hold."""
    problems = []
    for a in load_catalogue(path):
        f = a.path()
        if not f.is_file():
            problems.append(f"{a.name}: file {f} is missing; restore it or add the catalogue's assets again")
            continue
        try:
            now = inspect_asset(f, a.cls, a.licence, a.name)
        except LfusdError as e:
            problems.append(f"{a.name}: {e}")
            continue
        if now.sha256 != a.sha256:
            problems.append(f"{a.name}: {f} changed since it was added (content hash differs); run `lfusd assets add {f}` again")
        elif now.cls != a.cls or not np.allclose(now.bounds, a.bounds, atol=1e-5):
            problems.append(f"{a.name}: its recorded class or bounds differ from the file's; run `lfusd assets add {f}` again")
    return problems


def builtin_entries() -> list[dict]:
    """lfusd's procedural generators as catalogue entries (name, class, source)."""
    return [{"name": f"procedural:{cls}", "class": cls, "source": f"lfusd.author.scenes.{gen}"} for cls, gen in PROCEDURAL.items()]


def draw_assets(catalogues) -> dict[str, list[Asset]]:
    """The catalogues' assets by class, for a template (classes in :data:`DRAWN` only); every
    asset's files must still hash as recorded (a changed asset would silently change stages)."""
    from .stage import files_digest

    out: dict[str, list[Asset]] = {}
    for c in catalogues or ():
        for a in load_catalogue(c):
            f = a.path()
            if not f.is_file():
                raise LfusdError(f"asset {a.name} of catalogue {c} is missing ({f}); restore it or run `lfusd assets check`")
            if files_digest(content_files(f)) != a.sha256:
                raise LfusdError(f"asset {a.name} ({f}) changed since it was added to catalogue {c}; "
                                 f"run `lfusd assets add {f}` again")
            if a.cls in DRAWN:
                out.setdefault(a.cls, []).append(a)
    for pool in out.values():
        pool.sort(key=lambda a: (a.name, a.sha256))
    return out


def placement_matrix(asset: Asset) -> np.ndarray:
    """4x4 USD matrix (row vectors) taking the asset's points into an object frame of lfusd's
    world: Z up, metres, the bounds' x-y centre at the origin, the lowest point at z = 0, and the
    longer horizontal side along x (templates' kits face +x)."""
    from .stage import WorldFrame

    frame = WorldFrame(asset.up_axis, asset.meters_per_unit)
    lo, hi = np.asarray(asset.bounds[0], float), np.asarray(asset.bounds[1], float)
    turn = np.eye(3)
    if hi[1] - lo[1] > hi[0] - lo[0]:  # a quarter turn about z: (x, y) -> (-y, x)
        turn = np.array([[0.0, -1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 1.0]])
    centre = turn @ np.array([(lo[0] + hi[0]) / 2, (lo[1] + hi[1]) / 2, lo[2]])
    lin = turn @ frame.rotation * frame.meters_per_unit  # column-vector linear map
    m = np.eye(4)
    m[:3, :3] = lin.T
    m[3, :3] = -centre
    return m


def placed_size(asset: Asset) -> tuple[float, float, float]:
    """The asset's extent (x, y, z metres) in the frame of :func:`placement_matrix`."""
    d = np.asarray(asset.bounds[1], float) - np.asarray(asset.bounds[0], float)
    return (float(max(d[0], d[1])), float(min(d[0], d[1])), float(d[2])) if d[1] > d[0] else tuple(float(v) for v in d)

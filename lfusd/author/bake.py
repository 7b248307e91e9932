"""Baking catalogue assets with an outside generator (`lfusd assets bake`), and the clean-up that
makes their USD export fit lfusd (pxr only).

Infinigen (BSD-3-Clause) is the generator: its asset factories run in its own environment
(``.venv-infinigen``, scripts/setup_infinigen.sh; it pins bpy 4.2) through
lfusd/author/infinigen_runner.py, and export with Infinigen's own exporter
(infinigen/tools/export.py: baked textures, Blender 4.2's USD exporter). What that export gets
wrong for a renderer that follows UsdPreviewSurface, and :func:`clean_asset` fixes, each fix
logged and counted in a :class:`CleanReport`:

- ``lights``: the export carries Blender's world as a DomeLight reading a near-black image
  (``color_121212.hdr``). A stage with any light gets no light from lfusd, so the asset rendered
  alone is lit by that dome only: very dark. The asset's lights are removed (templates light
  their scenes; an unlit stage gets lfusd's neutral sky and sun).
- ``colour_spaces``: every baked texture is tagged ``sourceColorSpace = "sRGB"``; those that feed
  data inputs (roughness, metallic, normal, opacity, ...) are set to ``raw``. Read as sRGB, a
  flat normal map's (0.5, 0.5, 1) becomes (0.21, 0.21, 1): normals tilted about 40 degrees.
- ``normal_maps``: a normal map needs ``scale`` (2, 2, 2, 1) and ``bias`` (-1, -1, -1, 0) to
  map [0, 1] texels to [-1, 1] as UsdPreviewSurface specifies; they are added where missing.
- ``types``: the normal input is written as ``float3``; UsdPreviewSurface's is ``normal3f``
  (USD's validators refuse the asset otherwise).
- ``glass``: glass is exported with ``opacity`` 0 (invisible); it becomes lfusd's glass
  (lfusd.author.scenes.build.FINISHES: opacity 0.3, roughness 0.05) with its ior (1.5 if none).
- ``grounded``: the asset's lowest point is moved to 0 along its up axis (a translate on the
  default prim, in the asset's units).
- ``instanced``: meshes identical in every authored value but their transform and names (twigs,
  leaves, legs copied by the generator) become instanceable references to one prototype
  (a class prim holding the mesh and a copy of its material), so the geometry is stored once.

An asset over the triangle budget (drawn triangles, every copy counted) is refused, not
decimated: decimation would change the geometry the ground truth is verified against, and a
generator's other seed or a higher ``--max-triangles`` is the user's choice.
"""

from __future__ import annotations

import json
import logging
import os
import shutil
import subprocess
from dataclasses import dataclass, field
from pathlib import Path

from ..errors import LfusdError

log = logging.getLogger(__name__)

LICENCE_INFINIGEN = "BSD-3-Clause (Infinigen)"
MAX_TRIANGLES = 1_000_000  # the default budget of drawn triangles per baked asset
PYTHON_ENV = "LFUSD_INFINIGEN_PYTHON"  # Infinigen's interpreter, when not .venv-infinigen/bin/python
SETUP_SCRIPT = "scripts/setup_infinigen.sh"
PROTOTYPES = "/lfusd_prototypes"  # where instanced meshes' prototypes go (class prims, outside the default prim)
NORMAL_SCALE = (2.0, 2.0, 2.0, 1.0)
NORMAL_BIAS = (-1.0, -1.0, -1.0, 0.0)
GLASS_IOR = 1.5
# UsdPreviewSurface inputs that take colours (read as sRGB when so tagged); every other input is data
COLOUR_INPUTS = ("diffuseColor", "emissiveColor", "specularColor")

# Infinigen factory -> lfusd class (lfusd.author.vocabulary.OBJECTS); others need --class
FACTORY_CLASSES = {
    "ChairFactory": "chair", "BarChairFactory": "chair", "OfficeChairFactory": "chair", "ArmChairFactory": "chair",
    "TableDiningFactory": "table", "SideTableFactory": "table", "CoffeeTableFactory": "table",
    "TableCocktailFactory": "table", "SimpleDeskFactory": "table", "SidetableDeskFactory": "table",
    "SimpleBookcaseFactory": "shelf", "LargeShelfFactory": "shelf", "CellShelfFactory": "shelf",
    "TriangleShelfFactory": "shelf", "TVStandFactory": "shelf",
    "CabinetFactory": "cabinet", "SingleCabinetFactory": "cabinet", "KitchenCabinetFactory": "cabinet",
    "TreeFactory": "tree", "BushFactory": "tree",
    "LampFactory": "lamp", "DeskLampFactory": "lamp", "FloorLampFactory": "lamp",
    "BowlFactory": "bowl",
}
GENERATORS = ("infinigen",)


@dataclass
class CleanReport:
    """What :func:`clean_asset` fixed: per fix, how many times (see the module docstring)."""

    counts: dict[str, int] = field(default_factory=lambda: dict.fromkeys(
        ("lights", "colour_spaces", "normal_maps", "types", "glass", "grounded", "instanced"), 0))
    triangles: int = 0
    ground_shift: float = 0.0  # metres the asset moved up (negative: down)
    notes: list[str] = field(default_factory=list)

    def fix(self, kind: str, n: int, message: str, *args) -> None:
        if n:
            self.counts[kind] += n
            log.info(message, *args)
            self.notes.append(message % args)

    def summary(self) -> str:
        done = [f"{k.replace('_', ' ')} {v}" for k, v in self.counts.items() if v]
        return ", ".join(done) if done else "nothing to fix"


# -- the clean-up ---------------------------------------------------------------------------------

def _texture_uses(stage) -> dict:
    """For each UsdUVTexture shader (by path), the UsdPreviewSurface inputs it feeds directly."""
    from pxr import UsdShade

    uses: dict = {}
    for prim in stage.Traverse():
        sh = UsdShade.Shader(prim)
        if not sh or sh.GetIdAttr().Get() != "UsdPreviewSurface":
            continue
        for inp in sh.GetInputs():
            for src in inp.GetConnectedSources()[0]:
                uses.setdefault(src.source.GetPath(), []).append(inp.GetBaseName())
    return uses


def _fix_materials(stage, report: CleanReport) -> None:
    from pxr import Gf, Sdf, UsdShade

    uses = _texture_uses(stage)
    for prim in stage.Traverse():
        sh = UsdShade.Shader(prim)
        if not sh:
            continue
        kind = sh.GetIdAttr().Get()
        if kind == "UsdUVTexture":
            names = uses.get(prim.GetPath(), [])
            cs = sh.GetInput("sourceColorSpace")
            space = (cs.Get() if cs else None) or "auto"
            if names and all(n not in COLOUR_INPUTS for n in names) and space != "raw":
                sh.CreateInput("sourceColorSpace", Sdf.ValueTypeNames.Token).Set("raw")
                report.fix("colour_spaces", 1, "texture %s feeds %s: colour space %s -> raw", prim.GetPath(),
                           ", ".join(names), space)
            if "normal" in names and not (sh.GetInput("scale") and sh.GetInput("bias")
                                          and sh.GetInput("scale").GetAttr().HasAuthoredValue()):
                sh.CreateInput("scale", Sdf.ValueTypeNames.Float4).Set(Gf.Vec4f(*NORMAL_SCALE))
                sh.CreateInput("bias", Sdf.ValueTypeNames.Float4).Set(Gf.Vec4f(*NORMAL_BIAS))
                report.fix("normal_maps", 1, "normal map %s: scale (2, 2, 2, 1) and bias (-1, -1, -1, 0) added", prim.GetPath())
        elif kind == "UsdPreviewSurface":
            normal = sh.GetInput("normal")
            if normal and normal.GetTypeName() != Sdf.ValueTypeNames.Normal3f:
                # Blender writes float3; UsdPreviewSurface's normal is a normal3f (USD's validators insist)
                sources = [s.source.GetPrim().GetPath().AppendProperty(UsdShade.Utils.GetFullName(s.sourceName, s.sourceType))
                           for s in normal.GetConnectedSources()[0]]
                value = normal.Get() if not sources else None
                prim.RemoveProperty(normal.GetAttr().GetName())
                fixed = sh.CreateInput("normal", Sdf.ValueTypeNames.Normal3f)
                if sources:
                    fixed.GetAttr().SetConnections(sources)
                elif value is not None:
                    fixed.Set(Gf.Vec3f(*value))
                report.fix("types", 1, "%s.inputs:normal: float3 -> normal3f", prim.GetPath())
            opacity = sh.GetInput("opacity")
            if opacity and not opacity.HasConnectedSource() and opacity.Get() is not None and float(opacity.Get()) <= 0.0:
                from .scenes.build import FINISHES

                glass = FINISHES["glass"]
                opacity.Set(float(glass["opacity"]))
                rough = sh.GetInput("roughness")
                if not (rough and rough.HasConnectedSource()):
                    sh.CreateInput("roughness", Sdf.ValueTypeNames.Float).Set(float(glass["roughness"]))
                ior = sh.GetInput("ior")
                if not (ior and ior.Get()):
                    sh.CreateInput("ior", Sdf.ValueTypeNames.Float).Set(GLASS_IOR)
                report.fix("glass", 1, "material %s had opacity 0 (invisible glass): opacity %g, roughness %g, ior %g",
                           prim.GetParent().GetPath(), glass["opacity"], glass["roughness"],
                           float(sh.GetInput("ior").Get()))


def _remove_lights(stage, report: CleanReport) -> None:
    from pxr import UsdLux

    lights = [p.GetPath() for p in stage.Traverse() if p.HasAPI(UsdLux.LightAPI)]
    for path in lights:
        stage.RemovePrim(path)
    report.fix("lights", len(lights), "removed %d light(s) (%s): the exporter's world, which left the asset unlit",
               len(lights), ", ".join(str(p) for p in lights))


def _value_key(value):
    import numpy as np

    try:
        arr = np.asarray(value)
        if arr.dtype != object and arr.ndim >= 1:
            return (arr.dtype.str, arr.shape, arr.tobytes())
    except (TypeError, ValueError):
        pass
    return repr(value)


def _spec_key(layer, path) -> tuple:
    """Every authored value of the prim spec at ``path`` and below, but its names and transform."""
    spec = layer.GetPrimAtPath(path)
    props = []
    for prop in spec.properties:
        name = prop.name
        if name.startswith("xformOp") or name.startswith("userProperties:"):
            continue
        if hasattr(prop, "targetPathList"):
            props.append((name, tuple(str(p) for p in prop.targetPathList.GetAddedOrExplicitItems())))
        else:
            props.append((name, str(prop.typeName), _value_key(prop.default),
                          str(prop.GetInfo("interpolation")) if prop.HasInfo("interpolation") else ""))
    children = tuple((c.name, _spec_key(layer, c.path)) for c in spec.nameChildren)
    return (spec.typeName, tuple(sorted(props, key=lambda p: p[0])), children)


def _copy_with_paths(layer, src, dst) -> None:
    """Copy the prim spec ``src`` to ``dst``, retargeting connections and relationships inside it."""
    from pxr import Sdf

    Sdf.CreatePrimInLayer(layer, dst.GetParentPath())
    assert Sdf.CopySpec(layer, src, layer, dst)

    def fix(path):
        spec = layer.GetPrimAtPath(path)
        for prop in spec.properties:
            lst = prop.targetPathList if hasattr(prop, "targetPathList") else prop.connectionPathList
            items = list(lst.GetAddedOrExplicitItems())
            if items and any(p.HasPrefix(src) for p in items):
                lst.ClearEdits()
                lst.explicitItems = [p.ReplacePrefix(src, dst) if p.HasPrefix(src) else p for p in items]
        for c in spec.nameChildren:
            fix(c.path)

    fix(dst)


def _instance_copies(stage, report: CleanReport) -> None:
    from pxr import Sdf, UsdGeom

    layer = stage.GetRootLayer()
    groups: dict[tuple, list] = {}
    for prim in stage.Traverse():
        if prim.IsA(UsdGeom.Mesh) and layer.GetPrimAtPath(prim.GetPath()) is not None:
            groups.setdefault(_spec_key(layer, prim.GetPath()), []).append(prim.GetPath())
    for k, paths in enumerate(g for g in groups.values() if len(g) > 1):
        first = paths[0]
        proto = Sdf.Path(PROTOTYPES).AppendChild(f"{first.name}_{k}")
        with Sdf.ChangeBlock():
            if layer.GetPrimAtPath(PROTOTYPES) is None:  # abstract, like everything in it: nothing here draws
                Sdf.PrimSpec(layer, Sdf.Path(PROTOTYPES).name, Sdf.SpecifierClass, "Scope")
            pspec = Sdf.PrimSpec(layer.GetPrimAtPath(PROTOTYPES), proto.name, Sdf.SpecifierClass, "Xform")
            geom = proto.AppendChild(first.name)
            _copy_with_paths(layer, first, geom)
            gspec = layer.GetPrimAtPath(geom)
            for prop in list(gspec.properties):
                if prop.name.startswith("xformOp"):
                    gspec.RemoveProperty(prop)
            # the mesh's materials come along inside the prototype (a reference cannot reach outside it)
            outside = sorted({t for t in _targets(layer, geom) if not t.HasPrefix(proto)}, key=str)
            if outside:
                Sdf.PrimSpec(pspec, "Looks", Sdf.SpecifierDef, "Scope")
            for j, mat in enumerate(m for m in outside if layer.GetPrimAtPath(m) is not None):
                local = proto.AppendChild("Looks").AppendChild(f"{mat.name}_{j}")
                _copy_with_paths(layer, mat, local)
                _retarget(layer, geom, mat, local)
        for path in paths:
            old = layer.GetPrimAtPath(path)
            ops = {p.name: (p.typeName, p.default, p.variability) for p in old.properties if p.name.startswith("xformOp")}
            parent = layer.GetPrimAtPath(path.GetParentPath())
            with Sdf.ChangeBlock():
                del parent.nameChildren[path.name]
                spec = Sdf.PrimSpec(parent, path.name, Sdf.SpecifierDef, "Xform")
                for name, (type_name, value, variability) in ops.items():
                    a = Sdf.AttributeSpec(spec, name, type_name, variability)
                    a.default = value
                spec.referenceList.Prepend(Sdf.Reference("", proto))
                spec.instanceable = True
        report.fix("instanced", len(paths), "%d identical copies of mesh %s are instances of %s", len(paths), first, proto)


def _targets(layer, path) -> list:
    out = []
    spec = layer.GetPrimAtPath(path)
    for prop in spec.properties:
        if hasattr(prop, "targetPathList"):
            out += list(prop.targetPathList.GetAddedOrExplicitItems())
    for c in spec.nameChildren:
        out += _targets(layer, c.path)
    return out


def _retarget(layer, path, old, new) -> None:
    spec = layer.GetPrimAtPath(path)
    for prop in spec.properties:
        if hasattr(prop, "targetPathList"):
            items = list(prop.targetPathList.GetAddedOrExplicitItems())
            if old in items:
                prop.targetPathList.ClearEdits()
                prop.targetPathList.explicitItems = [new if p == old else p for p in items]
    for c in spec.nameChildren:
        _retarget(layer, c.path, old, new)


def _drawn_triangles(stage) -> int:
    from pxr import Usd, UsdGeom

    n = 0
    for prim in Usd.PrimRange.Stage(stage, Usd.TraverseInstanceProxies(Usd.PrimDefaultPredicate)):
        if prim.IsA(UsdGeom.Mesh) and UsdGeom.Imageable(prim).ComputeVisibility() != UsdGeom.Tokens.invisible:
            counts = UsdGeom.Mesh(prim).GetFaceVertexCountsAttr().Get()
            n += int(sum(max(int(c) - 2, 0) for c in counts)) if counts is not None else 0
    return n


def _ground(stage, report: CleanReport) -> None:
    """Move the asset's lowest drawn point to 0 along its up axis (its points, as the catalogue
    measures them: authored extents can be looser than the geometry)."""
    from pxr import Gf, UsdGeom

    from .geometry import StageGeometry

    root = stage.GetDefaultPrim()
    if not root or not root.IsA(UsdGeom.Xformable):
        raise LfusdError(f"asset {stage.GetRootLayer().identifier} has no transformable default prim to ground; "
                         "give an asset whose default prim is an Xform")
    geometry = StageGeometry(stage)
    t = stage.GetStartTimeCode() if stage.HasAuthoredTimeCodeRange() else 0.0
    lows = [float(m.vertices[:, 2].min()) for m in (geometry.mesh(p, t) for p in geometry.parts) if len(m.vertices)]
    if not lows or abs(min(lows)) <= 1e-7:
        return
    low = min(lows)  # metres, in lfusd's world (Z up)
    mpu = geometry.frame.meters_per_unit
    axis = 1 if geometry.frame.up_axis == "Y" else 2
    shift = [0.0, 0.0, 0.0]
    shift[axis] = -low / mpu  # scene units along the asset's up axis
    xf = UsdGeom.Xformable(root)
    order = xf.GetOrderedXformOps()
    op = xf.AddTranslateOp(UsdGeom.XformOp.PrecisionDouble, "lfusdGround")
    op.Set(Gf.Vec3d(*shift))
    xf.SetXformOpOrder([op] + order, xf.GetResetXformStack())  # outermost: along the stage's own axes
    report.ground_shift = -low
    report.fix("grounded", 1, "lowest point was at %.4g m along %s: moved to 0", low, "yz"[axis - 1])


def clean_asset(src: str | Path, dst: str | Path, cls: str | None = None, licence: str | None = None,
                max_triangles: int = MAX_TRIANGLES, label: str | None = None) -> CleanReport:
    """Write ``dst``, the asset at ``src`` with what its Infinigen export gets wrong fixed (see the
    module docstring), labelled ``cls`` and with ``licence`` in its metadata when given; the
    textures it reads are copied beside ``dst`` at the same relative paths. LfusdError, with
    nothing written, when it has more than ``max_triangles`` drawn triangles (``label`` names the
    asset in messages, default ``src``)."""
    from pxr import Sdf, Usd, UsdSemantics

    from .stage import usd_warnings
    from .vocabulary import OBJECTS

    src, dst = Path(src), Path(dst)
    if cls is not None and cls not in OBJECTS:
        raise LfusdError(f"--class {cls!r} is not an object class lfusd knows; use one of {', '.join(OBJECTS)}")
    with usd_warnings():
        source = Usd.Stage.Open(str(src))
    report = CleanReport(triangles=_drawn_triangles(source))
    if report.triangles > max_triangles:
        raise LfusdError(f"asset {label or src} has {report.triangles} triangles, over the budget of {max_triangles} "
                         "(lfusd refuses, it does not decimate); bake another seed or raise --max-triangles")
    if dst.exists():
        raise LfusdError(f"{dst} already exists; lfusd does not overwrite it: remove it or choose another output")
    dst.parent.mkdir(parents=True, exist_ok=True)
    layer = Sdf.Layer.CreateNew(str(dst))
    layer.TransferContent(source.GetRootLayer())
    stage = Usd.Stage.Open(layer)
    _remove_lights(stage, report)
    _fix_materials(stage, report)
    _ground(stage, report)
    _instance_copies(stage, report)
    root = stage.GetDefaultPrim()
    if cls:
        UsdSemantics.LabelsAPI.Apply(root, "class").CreateLabelsAttr().Set([cls])
    if licence:
        data = dict(layer.customLayerData or {})
        data["license"] = licence
        layer.customLayerData = data
    # the textures the cleaned asset still reads, copied beside it at the same relative paths
    if dst.parent.resolve() != src.parent.resolve():
        for name in _texture_paths(stage):
            if os.path.isabs(name):
                continue
            s, d = src.parent / name, dst.parent / name
            if s.is_file() and not d.exists():
                d.parent.mkdir(parents=True, exist_ok=True)
                shutil.copy2(s, d)
    layer.Save()
    log.info("cleaned %s -> %s: %s", src, dst, report.summary())
    return report


def _texture_paths(stage) -> list[str]:
    from pxr import Sdf, UsdShade

    out = []
    for prim in stage.Traverse():
        sh = UsdShade.Shader(prim)
        if sh and sh.GetIdAttr().Get() == "UsdUVTexture":
            f = sh.GetInput("file")
            v = f.Get() if f else None
            if isinstance(v, Sdf.AssetPath) and v.path:
                out.append(v.path)
    return sorted(set(out))


# -- running Infinigen ----------------------------------------------------------------------------

def infinigen_python(python: str | Path | None = None) -> Path:
    """Infinigen's interpreter: ``python``, else $LFUSD_INFINIGEN_PYTHON, else the
    ``.venv-infinigen/bin/python`` that scripts/setup_infinigen.sh made in lfusd's project folder;
    LfusdError (naming the set-up script) when it does not exist. Never a program found in the
    current folder: a folder someone else made would get its program run."""
    given = python or os.environ.get(PYTHON_ENV)
    candidate = Path(given) if given else Path(__file__).resolve().parents[2] / ".venv-infinigen/bin/python"
    if candidate.is_file() and os.access(candidate, os.X_OK):
        return candidate
    raise LfusdError(f"Infinigen's environment is missing ({candidate} not found); run {SETUP_SCRIPT} "
                     f"(opt-in: a few minutes, about 2.5 GB) or name its interpreter with --python or ${PYTHON_ENV}")


def factory_class(factory: str, cls: str | None) -> str:
    """The lfusd class a factory's asset gets: ``cls``, else :data:`FACTORY_CLASSES`."""
    if cls:
        return cls
    if factory in FACTORY_CLASSES:
        return FACTORY_CLASSES[factory]
    raise LfusdError(f"lfusd has no class for Infinigen factory {factory}; pass --class CLASS "
                     f"(known factories: {', '.join(sorted(FACTORY_CLASSES))})")


def _exported(line: str, factory: str, seed: int) -> Path:
    """The asset file the runner's ``LFUSD_BAKE {...}`` line names, or one line when it names none
    or the file is not there."""
    try:
        usd = json.loads(line[len("LFUSD_BAKE "):])["usd"]
        path = Path(usd) if isinstance(usd, str) and usd else None
    except (ValueError, KeyError, TypeError):
        path = None
    if path is None or not path.is_file():
        raise LfusdError(f"Infinigen reported no asset file for {factory} seed {seed} ({path or 'no path'} is missing); "
                         "rerun it with -vv to see Infinigen's output, or check its environment with scripts/setup_infinigen.sh")
    return path


@dataclass
class BakeResult:
    asset: object  # lfusd.author.catalogue.Asset
    catalogue: Path
    report: CleanReport
    seconds: float


def bake(generator: str, factory: str, seed: int, catalogue: str | Path, out: str | Path | None = None,
         cls: str | None = None, python: str | Path | None = None, max_triangles: int = MAX_TRIANGLES,
         texture_size: int = 1024) -> BakeResult:
    """Run ``generator``'s ``factory`` with ``seed`` in its own environment, clean its export
    (:func:`clean_asset`) into ``out/FACTORY_SEED/FACTORY_SEED.usdc`` (``out`` defaults to the
    catalogue's folder) and add it to ``catalogue``. Everything is checked before anything is
    written; on a failure the asset's folder, which lfusd made, is removed."""
    import time

    from .catalogue import add_assets, catalogue_path
    from .vocabulary import OBJECTS

    if generator not in GENERATORS:
        raise LfusdError(f"unknown generator {generator!r}; lfusd bakes with {', '.join(GENERATORS)}")
    cls = factory_class(factory, cls)
    if cls not in OBJECTS:
        raise LfusdError(f"--class {cls!r} is not an object class lfusd knows; use one of {', '.join(OBJECTS)}")
    if seed < 0:
        raise LfusdError(f"--seed {seed} is negative; give a seed >= 0")
    if max_triangles < 1 or texture_size < 16:
        raise LfusdError(f"--max-triangles {max_triangles} / --texture-size {texture_size}: give at least 1 triangle "
                         "and 16 pixels")
    exe = infinigen_python(python)
    cat = catalogue_path(catalogue, catalogue)
    if cat.suffix.lower() != ".json":
        raise LfusdError(f"catalogue {cat} must be a .json file; pass --catalogue FILE.json")
    if not cat.parent.is_dir():
        raise LfusdError(f"folder {cat.parent} of catalogue {cat} does not exist; create it or pass another --catalogue")
    name = f"{factory}_{seed}"
    folder = Path(out) if out is not None else cat.parent
    asset_dir = folder / name
    if asset_dir.exists():
        raise LfusdError(f"{asset_dir} already exists; lfusd does not overwrite it: remove it or pass another -o")
    start = time.monotonic()
    asset_dir.mkdir(parents=True)
    try:
        raw = asset_dir.resolve() / ".infinigen"
        cmd = [str(exe), str(Path(__file__).with_name("infinigen_runner.py")), "--factory", factory, "--seed", str(seed),
               "--out", str(raw / name), "--texture-size", str(texture_size)]
        log.info("running Infinigen: %s", " ".join(cmd))
        proc = subprocess.run(cmd, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True, cwd=asset_dir)
        log.debug("Infinigen's output:\n%s", proc.stdout)
        lines = [ln for ln in proc.stdout.splitlines() if ln.startswith("LFUSD_BAKE ")]
        if proc.returncode != 0 or not lines:
            last = next((ln for ln in reversed(proc.stdout.splitlines()) if ln.strip()), "no output")
            raise LfusdError(f"Infinigen failed on {factory} seed {seed} (exit {proc.returncode}): {last.strip()}")
        exported = _exported(lines[-1], factory, seed)
        report = clean_asset(exported, asset_dir / f"{name}.usdc", cls=cls, licence=LICENCE_INFINIGEN,
                             max_triangles=max_triangles, label=f"{factory} seed {seed}")
        shutil.rmtree(raw)
        path, added = add_assets(asset_dir / f"{name}.usdc", cat, cls, LICENCE_INFINIGEN)
    except BaseException:
        shutil.rmtree(asset_dir, ignore_errors=True)
        raise
    return BakeResult(asset=added[0], catalogue=path, report=report, seconds=time.monotonic() - start)

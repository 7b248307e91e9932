"""Dataset recipes: ``lfusd dataset make RECIPE.toml -o DIR``.

A recipe (TOML, read with tomllib) names the render settings once and one or more *parts*, each
a number of scenes drawn from templates and seeds (lfusd.author.scenes.generate, which also adds
the rigs). Every scene is generated, rendered (``render-video`` for a dynamic part, ``render`` of
its one frame for a static one; local processes or Ray), verified (lfusd.truth.verify) and
measured; the dataset card (CARD.md, card.json, plots/*.png) sums the scenes' statistics.

Splits (for training): a part may name its ``split`` (train, val or test; every part then does).
A scene is its (template, seed) (the dynamic variant of a seed is its static scene plus movers), and
no scene may be in two splits; ``dataset.held_out`` names templates that only test parts may use (a
network is then scored on scenes of a kind it never saw). :func:`split_scenes` lists a made
dataset's scene folders per split.

Scene k of a part uses template ``templates[k % len(templates)]`` and seed ``first_seed + k``;
a rig range ``[lo, hi]`` gives it ``lo + seed % (hi - lo + 1)`` rigs. Each finished scene leaves
a record ``scenes/<scene>.json`` (its spec, verification and statistics), written last: a rerun
skips every scene whose record matches its spec and says verified, and finishes the others (the
render itself resumes view by view).

Statistics, over every rig and frame of a scene and the recipe's ``stats_views`` (the centre
view, or all): disparity (px per baseline step, pixels with a surface) min/max and histogram;
|flow_fwd| histogram over valid pixels (frames with a next frame); motion coverage (per view and
frame, the fraction of pixels with valid |flow_fwd| > 0.01 px, lfusd.truth.coverage's rule);
class frequencies (pixels per semantic class). Histograms use the fixed edges below, so scenes add.
"""

from __future__ import annotations

import json
import logging
import tomllib
from dataclasses import asdict, dataclass, field
from pathlib import Path

import numpy as np

from . import layout
from .data.sensor import SensorModel
from .errors import LfusdError

log = logging.getLogger(__name__)

DISPARITY_EDGES = [0.0, 0.5, 1, 2, 4, 8, 16, 32, 64, 128, 256, 512, float("inf")]  # px
FLOW_EDGES = [0.0, 0.01, 0.1, 0.5, 1, 2, 4, 8, 16, 32, 64, 128, float("inf")]  # px
MOVING = 0.01  # px: lfusd.truth.coverage.THRESHOLD (not imported: truth's coverage module pulls in the readers anyway)
GOAL_COVERAGE = 0.05
VERIFY_MODES = ("all", "centre", "none")
STATS_VIEWS = ("centre", "all")
SPLITS = ("train", "val", "test")
EXECUTORS = ("local", "ray")
RECORD_VERSION = 1
# The most scenes one recipe makes: 1e8 scenes is a typo, refused before a list of them is made
# (each scene is a stage and a dataset folder; the disk check below catches the realistic excess).
MAX_SCENES = 100_000


@dataclass(frozen=True)
class Part:
    """One part of a recipe: ``scenes`` scenes of ``templates`` from ``first_seed`` on."""

    name: str
    templates: tuple[str, ...]
    scenes: int
    first_seed: int = 0
    rigs: tuple[int, int] = (1, 1)
    frames: int = 1
    dynamic: bool = False
    split: str | None = None  # train, val or test (a recipe's parts name one each, or none does)


@dataclass(frozen=True)
class Recipe:
    name: str
    grid: tuple[int, int]
    resolution: tuple[int, int]
    parts: tuple[Part, ...]
    samples: int = 16
    device: str = "auto"
    executor: str = "local"
    ray_address: str | None = None
    workers: int = 1
    verify: str = "all"
    stats_views: str = "centre"
    thresholds: tuple[tuple[str, float], ...] = ()  # [dataset.thresholds]: verify limits replaced (KEY = VALUE)
    catalogues: tuple[str, ...] = ()  # dataset.catalogues: asset catalogue files (lfusd.author.catalogue), resolved
    lens: tuple[float, float] = (0.0, 0.0)  # dataset.fstop, dataset.focus: every view's thin lens (render-video --fstop --focus)
    shutter: float = 0.0  # dataset.shutter: motion blur over this fraction of a frame and the key blur (render-video --shutter)
    materials: bool = False  # dataset.materials: the material masks and depth_behind (render-video --materials)
    sensor: SensorModel | None = None  # [dataset.sensor]: the rgb_noisy key's sensor model (lfusd.data.sensor); None: off
    held_out: tuple[str, ...] = ()  # dataset.held_out: templates only test parts may use
    # dataset.lens = [K1, K2, P1, P2, K3], lens_seed, lens_spread: every view's lens distortion (render-video --lens ...); () off
    distortion: tuple[float, ...] = ()
    distortion_seed: int | None = None
    distortion_spread: float = 0.0


@dataclass(frozen=True)
class SceneSpec:
    """One scene of a recipe: what generates and renders it (the record's identity)."""

    name: str
    part: str
    template: str
    seed: int
    rigs: int
    frames: int
    dynamic: bool
    grid: tuple[int, int]
    resolution: tuple[int, int]
    samples: int
    catalogues: tuple[str, ...] = ()  # asset catalogues the template draws from (left out of a record when none)
    split: str | None = None  # its part's split (left out of a record when none)


# -- reading and checking a recipe ------------------------------------------------------------

def _bad(source: str, field_: str, got, fix: str) -> LfusdError:
    return LfusdError(f"recipe {source}: {field_} {fix}, got {got!r}")


def _get(table: dict, key: str, kind, source: str, where: str, fix: str, default=...):
    if key not in table:
        if default is ...:
            raise LfusdError(f"recipe {source}: {where}{key} is missing; {fix}")
        return default
    v = table[key]
    if kind is int and (isinstance(v, bool) or not isinstance(v, int)):
        raise _bad(source, where + key, v, fix)
    if kind is not int and not isinstance(v, kind):
        raise _bad(source, where + key, v, fix)
    return v


def _pair(table: dict, key: str, source: str, where: str, fix: str, lo: int = 1, default=...) -> tuple[int, int]:
    v = _get(table, key, (list, int), source, where, fix, default)
    if isinstance(v, int) and not isinstance(v, bool):
        v = [v, v]
    if not (isinstance(v, list) and len(v) == 2 and all(isinstance(x, int) and not isinstance(x, bool) and x >= lo for x in v)):
        raise _bad(source, where + key, table.get(key, v), fix)
    return int(v[0]), int(v[1])


def parse_recipe(data: dict, source: str = "<recipe>") -> Recipe:
    """A :class:`Recipe` from parsed TOML; LfusdError in one line naming the bad field and the fix."""
    from .author.scenes import TEMPLATES

    known_top = {"dataset", "part"}
    for k in data:
        if k not in known_top:
            raise LfusdError(f"recipe {source}: unknown table [{k}]; use [dataset] and [[part]]")
    ds = data.get("dataset")
    if not isinstance(ds, dict):
        raise LfusdError(f"recipe {source}: [dataset] is missing; add a [dataset] table with name, grid and resolution")
    known = {"name", "grid", "resolution", "samples", "device", "executor", "ray_address", "workers", "verify", "stats_views", "thresholds",
             "catalogues", "sensor", "materials", "shutter", "fstop", "focus", "held_out", "lens", "lens_seed", "lens_spread"}
    for k in ds:
        if k not in known:
            raise LfusdError(f"recipe {source}: unknown field dataset.{k}; use one of {', '.join(sorted(known))}")
    w = "dataset."
    name = _get(ds, "name", str, source, w, "must be a name (a string)")
    grid = _pair(ds, "grid", source, w, "must be [ROWS, COLS] of positive integers")
    resolution = _pair(ds, "resolution", source, w, "must be [WIDTH, HEIGHT] of positive integers")
    samples = _get(ds, "samples", int, source, w, "must be a positive integer", 16)
    workers = _get(ds, "workers", int, source, w, "must be a positive integer", 1)
    for k, v in (("samples", samples), ("workers", workers)):
        if v < 1:
            raise _bad(source, w + k, v, "must be a positive integer")
    device = _get(ds, "device", str, source, w, "must be a string", "auto")
    from .render.request import DEVICES

    if device not in DEVICES:
        raise _bad(source, w + "device", device, f"must be one of {', '.join(DEVICES)}")
    executor = _get(ds, "executor", str, source, w, "must be a string", "local")
    if executor not in EXECUTORS:
        raise _bad(source, w + "executor", executor, f"must be one of {', '.join(EXECUTORS)}")
    ray_address = _get(ds, "ray_address", str, source, w, "must be an address string", None)
    if ray_address and executor != "ray":
        raise _bad(source, w + "ray_address", ray_address, 'needs dataset.executor = "ray"')
    verify = _get(ds, "verify", str, source, w, "must be a string", "all")
    if verify not in VERIFY_MODES:
        raise _bad(source, w + "verify", verify, f"must be one of {', '.join(VERIFY_MODES)}")
    stats_views = _get(ds, "stats_views", str, source, w, "must be a string", "centre")
    if stats_views not in STATS_VIEWS:
        raise _bad(source, w + "stats_views", stats_views, f"must be one of {', '.join(STATS_VIEWS)}")
    raw_thresholds = _get(ds, "thresholds", dict, source, w, "must be a table of KEY = LIMIT", {})
    from .truth.verify import THRESHOLDS

    thresholds = []
    for k, v in raw_thresholds.items():
        if k not in THRESHOLDS:
            raise _bad(source, f"{w}thresholds.{k}", k, f"must name a verified key ({', '.join(THRESHOLDS)})")
        if isinstance(v, bool) or not isinstance(v, (int, float)) or not v > 0:
            raise _bad(source, f"{w}thresholds.{k}", v, "must be a positive number")
        thresholds.append((k, float(v)))

    raw_catalogues = _get(ds, "catalogues", list, source, w, "must be a list of catalogue files", [])
    catalogues = []
    for c in raw_catalogues:
        if not isinstance(c, str) or not c:
            raise _bad(source, w + "catalogues", c, "must list catalogue files (paths relative to the recipe's folder)")
        p = Path(c).expanduser()
        if not p.is_absolute() and source != "<recipe>":
            p = Path(source).parent / p
        from .author.catalogue import load_catalogue

        load_catalogue(p)  # a missing or foreign file: refused here, before any scene is made
        catalogues.append(str(p.resolve()))

    held_out = _get(ds, "held_out", list, source, w, "must be a list of templates kept for test parts", [])
    for t in held_out:
        if t not in TEMPLATES:
            raise _bad(source, w + "held_out", t, f"must list templates among {', '.join(TEMPLATES)}")

    raw_parts = data.get("part")
    if not isinstance(raw_parts, list) or not raw_parts:
        raise LfusdError(f"recipe {source}: no [[part]]; add at least one [[part]] with name, templates and scenes")
    parts, names = [], set()
    part_known = {"name", "templates", "scenes", "first_seed", "rigs", "frames", "dynamic", "split"}
    for i, p in enumerate(raw_parts):
        w = f"part[{i}]."
        for k in p:
            if k not in part_known:
                raise LfusdError(f"recipe {source}: unknown field {w}{k}; use one of {', '.join(sorted(part_known))}")
        pname = _get(p, "name", str, source, w, "must be a name (letters, digits, _ or -)")
        if not pname or not all(c.isalnum() or c in "_-" for c in pname) or pname in names:
            raise _bad(source, w + "name", pname, "must be a unique name of letters, digits, _ or -")
        names.add(pname)
        w = f"part.{pname}."
        templates = _get(p, "templates", list, source, w, f"must be a list of templates ({', '.join(TEMPLATES)})")
        for t in templates:
            if t not in TEMPLATES:
                raise _bad(source, w + "templates", t, f"must list templates among {', '.join(TEMPLATES)}")
        if not templates:
            raise _bad(source, w + "templates", templates, f"must list at least one of {', '.join(TEMPLATES)}")
        scenes = _get(p, "scenes", int, source, w, "must be a positive integer")
        first_seed = _get(p, "first_seed", int, source, w, "must be a non-negative integer", 0)
        frames = _get(p, "frames", int, source, w, "must be a positive integer", 1)
        dynamic = _get(p, "dynamic", bool, source, w, "must be true or false", False)
        rigs = _pair(p, "rigs", source, w, "must be a rig count 1-10 or a range [LO, HI] within 1-10", default=1)
        split = _get(p, "split", str, source, w, f"must be one of {', '.join(SPLITS)}", None)
        if split is not None and split not in SPLITS:
            raise _bad(source, w + "split", split, f"must be one of {', '.join(SPLITS)}")
        if scenes < 1:
            raise _bad(source, w + "scenes", scenes, "must be a positive integer")
        if first_seed < 0:
            raise _bad(source, w + "first_seed", first_seed, "must be a non-negative integer")
        if frames < 1:
            raise _bad(source, w + "frames", frames, "must be a positive integer")
        if frames > layout.MAX_FRAMES:
            raise _bad(source, w + "frames", frames, f"must be at most {layout.MAX_FRAMES} (the frames a dataset holds)")
        if scenes > MAX_SCENES or sum(q.scenes for q in parts) + scenes > MAX_SCENES:
            raise _bad(source, w + "scenes", scenes, f"must keep the recipe's scenes at most {MAX_SCENES} in all")
        if not (1 <= rigs[0] <= rigs[1] <= 10):
            raise _bad(source, w + "rigs", p.get("rigs"), "must be a rig count 1-10 or a range [LO, HI] within 1-10")
        if dynamic:
            if frames < 2:
                raise _bad(source, w + "frames", frames, "must be at least 2 for a dynamic part (motion needs a next frame)")
            static_only = [t for t in templates if TEMPLATES[t].animate is None]
            if static_only:
                raise _bad(source, w + "templates", static_only[0], "must have a dynamic variant in a dynamic part; remove it or set dynamic = false")
        elif frames != 1:
            raise _bad(source, w + "frames", frames, "must be 1 in a static part (set dynamic = true for a video)")
        parts.append(Part(pname, tuple(templates), scenes, first_seed, rigs, frames, dynamic, split))
    _check_splits(parts, held_out, source)
    from .camera import check_rig_size

    check_rig_size(grid, resolution)
    return Recipe(name, grid, resolution, tuple(parts), samples, device, executor, ray_address, workers, verify, stats_views,
                  tuple(sorted(thresholds)), tuple(catalogues), _lens(ds, source), _shutter(ds, source),
                  _get(ds, "materials", bool, source, w, "must be true or false", False),
                  _sensor(ds.get("sensor"), source), tuple(held_out), *_distortion(ds, source))


def _distortion(ds: dict, source: str) -> tuple[tuple[float, ...], int | None, float]:
    """(coefficients, seed, spread) of dataset.lens, lens_seed and lens_spread (checked as render-video's options are)."""
    from .camera import DISTORTION_COEFFS, Distortion

    coeffs = ds.get("lens", [])
    if not isinstance(coeffs, list) or len(coeffs) not in (0, len(DISTORTION_COEFFS)) or \
            any(isinstance(c, bool) or not isinstance(c, (int, float)) for c in coeffs):
        raise _bad(source, "dataset.lens", coeffs, "must be [K1, K2, P1, P2, K3] (OpenCV's distCoeffs, e.g. [-0.2, 0.05, 0, 0, 0])")
    seed = ds.get("lens_seed")
    if seed is not None and (isinstance(seed, bool) or not isinstance(seed, int)):
        raise _bad(source, "dataset.lens_seed", seed, "must be an integer")
    spread = ds.get("lens_spread", 0.0)
    if isinstance(spread, bool) or not isinstance(spread, (int, float)):
        raise _bad(source, "dataset.lens_spread", spread, "must be a non-negative number")
    from .render.request import check_lens

    try:
        check_lens(Distortion(*map(float, coeffs)) if coeffs else None, seed, float(spread),
                   ("dataset.lens", "dataset.lens_seed", "dataset.lens_spread"))
    except LfusdError as e:
        raise LfusdError(f"recipe {source}: {e}") from None
    return tuple(float(c) for c in coeffs), seed, float(spread)


def _lens(ds: dict, source: str) -> tuple[float, float]:
    values = []
    for k in ("fstop", "focus"):
        v = ds.get(k, 0.0)
        if isinstance(v, bool) or not isinstance(v, (int, float)) or not v >= 0:
            raise _bad(source, "dataset." + k, v, "must be a non-negative number")
        values.append(float(v))
    if bool(values[0]) != bool(values[1]):
        raise _bad(source, "dataset.fstop", values[0], "and dataset.focus go together (e.g. fstop = 2.8, focus = 3.0)")
    return values[0], values[1]


def _shutter(ds: dict, source: str) -> float:
    v = ds.get("shutter", 0.0)
    if isinstance(v, bool) or not isinstance(v, (int, float)) or not 0 <= v <= 1:
        raise _bad(source, "dataset.shutter", v, "must be a fraction of a frame in 0-1 (e.g. 0.5)")
    return float(v)


def _sensor(table, source: str) -> SensorModel | None:
    """[dataset.sensor]: any of SensorModel's fields (lfusd.data.sensor); the table turns the sensor on."""
    if table is None:
        return None
    fields = SensorModel.__dataclass_fields__
    if not isinstance(table, dict):
        raise _bad(source, "dataset.sensor", table, f"must be a table of {', '.join(fields)}")
    for k, v in table.items():
        if k not in fields:
            raise LfusdError(f"recipe {source}: unknown field dataset.sensor.{k}; use one of {', '.join(fields)}")
        if isinstance(v, bool) or not isinstance(v, (int, float)) or (k in ("jpeg", "seed") and not isinstance(v, int)):
            raise _bad(source, f"dataset.sensor.{k}", v, "must be an integer" if k in ("jpeg", "seed") else "must be a number")
    try:
        return SensorModel(**table).check()
    except LfusdError as e:
        raise LfusdError(f"recipe {source}: dataset.{e}") from None


def _check_splits(parts: list[Part], held_out: list[str], source: str) -> None:
    """Splits are all or none, disjoint in scenes (template, seed), and held-out templates are in test parts only."""
    named = [p for p in parts if p.split is not None]
    if named and len(named) != len(parts):
        p = next(p for p in parts if p.split is None)
        raise _bad(source, f"part.{p.name}.split", None, f"must be set when other parts name theirs ({', '.join(SPLITS)})")
    if held_out and not named:
        raise _bad(source, "dataset.held_out", held_out, "needs parts with a split (held-out templates go to test parts)")
    owner: dict[tuple[str, int], tuple[str, str]] = {}
    for p in named:
        for t in held_out:
            if t in p.templates and p.split != "test":
                raise _bad(source, f"part.{p.name}.templates", t, f"must not hold the held-out template {t!r} in a {p.split} part; "
                           "move it to a test part")
        for k in range(p.scenes):
            key = (p.templates[k % len(p.templates)], p.first_seed + k)
            other = owner.setdefault(key, (p.split, p.name))
            if other[0] != p.split:
                raise _bad(source, f"part.{p.name}.first_seed", p.first_seed,
                           f"must keep its scenes out of part {other[1]} ({other[0]}): both make {key[0]} seed {key[1]}; "
                           "give the parts seed ranges that do not overlap")
    for t in held_out:
        if not any(t in p.templates for p in named):
            raise _bad(source, "dataset.held_out", t, "must name templates that a test part uses")


def load_recipe(path) -> Recipe:
    """Read and check the recipe file at ``path``."""
    path = Path(path)
    try:
        text = path.read_text()
    except OSError as e:
        raise LfusdError(f"cannot read recipe {path} ({e.strerror or e}); give an existing .toml file") from None
    try:
        data = tomllib.loads(text)
    except tomllib.TOMLDecodeError as e:
        raise LfusdError(f"recipe {path} is not valid TOML ({e}); fix the syntax") from None
    return parse_recipe(data, str(path))


def scene_specs(recipe: Recipe) -> list[SceneSpec]:
    """Every scene of the recipe, in order (deterministic)."""
    out = []
    for p in recipe.parts:
        for k in range(p.scenes):
            template, seed = p.templates[k % len(p.templates)], p.first_seed + k
            lo, hi = p.rigs
            out.append(SceneSpec(f"{p.name}_{k:03d}_{template}_s{seed}", p.name, template, seed, lo + seed % (hi - lo + 1),
                                 p.frames, p.dynamic, recipe.grid, recipe.resolution, recipe.samples, recipe.catalogues, p.split))
    return out


# -- statistics -------------------------------------------------------------------------------

def histogram(values: np.ndarray, edges) -> list[int]:
    """Counts of ``values`` in [edges[i], edges[i+1]) (values below edges[0] are left out)."""
    idx = np.searchsorted(np.asarray(edges, np.float64), np.asarray(values, np.float64).ravel(), side="right") - 1
    idx = idx[(idx >= 0) & (idx < len(edges) - 1)]
    return np.bincount(idx, minlength=len(edges) - 1).astype(int).tolist()


def scene_stats(root: Path, stats_views: str = "centre") -> dict:
    """The statistics of one rendered scene folder (see the module docstring), with pixel counts."""
    from .data.dataset import open_datasets

    disp_hist = [0] * (len(DISPARITY_EDGES) - 1)
    flow_hist = [0] * (len(FLOW_EDGES) - 1)
    dmin, dmax, surface_px, flow_px = float("inf"), 0.0, 0, 0
    classes: dict[str, int] = {}
    coverage: dict[str, list[float]] = {}
    pixels = 0
    for ds in open_datasets(root, "all"):
        views = [ds.rig.centre_view] if stats_views == "centre" else [tuple(v) for v in ds.views]
        done = set(ds.frames)
        motion = ds.record.settings.motion and (ds.keys is None or "flow_fwd" in ds.keys)
        for view in views:
            key = f"{ds.rig_name} {view[0]:02d}_{view[1]:02d}"
            series = coverage.setdefault(key, [])
            for f in ds.frames:
                depth = np.asarray(ds.read(f, view, "depth"))
                pixels += depth.size
                surface = np.isfinite(depth)
                d = np.asarray(ds.read(f, view, "disparity"), np.float64)[surface]
                surface_px += int(d.size)
                if d.size:
                    dmin, dmax = min(dmin, float(d.min())), max(dmax, float(d.max()))
                    disp_hist = [a + b for a, b in zip(disp_hist, histogram(d, DISPARITY_EDGES))]
                sem = np.asarray(ds.read(f, view, "semantic")).ravel()
                for cid, n in enumerate(np.bincount(sem, minlength=len(ds.classes))):
                    if n:
                        label = ds.classes[cid] if cid < len(ds.classes) else str(cid)
                        classes[label or "unlabelled"] = classes.get(label or "unlabelled", 0) + int(n)
                if motion and f + 1 in done:
                    flow = np.asarray(ds.read(f, view, "flow_fwd"), np.float64)
                    valid = np.asarray(ds.read(f, view, "valid_fwd"), bool)
                    mag = np.linalg.norm(flow, axis=-1)
                    flow_px += int(valid.sum())
                    flow_hist = [a + b for a, b in zip(flow_hist, histogram(mag[valid], FLOW_EDGES))]
                    series.append(float((valid & (mag > MOVING)).sum() / valid.size))
            if not series:
                del coverage[key]
    return {
        "pixels": pixels,
        "disparity": {"pixels": surface_px, "min": dmin if surface_px else None, "max": dmax if surface_px else None,
                      "edges": DISPARITY_EDGES, "counts": disp_hist},
        "flow": {"pixels": flow_px, "edges": FLOW_EDGES, "counts": flow_hist},
        "coverage": coverage,
        "classes": classes,
    }


def _coverage_summary(series: list[float]) -> dict:
    a = np.asarray(series, np.float64)
    n = int(a.size)
    return {"frames": n, "any": float(np.mean(a > 0)) if n else 0.0, "goal": float(np.mean(a >= GOAL_COVERAGE)) if n else 0.0,
            "mean": float(a.mean()) if n else 0.0}


# -- making the dataset -----------------------------------------------------------------------

@dataclass
class MakeResult:
    """What one `make_dataset` run did."""

    scenes: list[str] = field(default_factory=list)
    made: list[str] = field(default_factory=list)
    skipped: list[str] = field(default_factory=list)
    failed: list[str] = field(default_factory=list)  # verification failed
    card: dict = field(default_factory=dict)


def _spec_dict(spec: SceneSpec) -> dict:
    d = asdict(spec)
    if not d["catalogues"]:
        del d["catalogues"]  # records of recipes without catalogues keep their identity
    if d["split"] is None:
        del d["split"]  # likewise records of recipes without splits
    return json.loads(json.dumps(d))  # tuples as lists, as they come back from a record


def split_scenes(root) -> dict[str, list[Path]]:
    """The scene folders of a made recipe dataset per split (``train``, ``val``, ``test``), in recipe
    order, from the scenes' records: only scenes that are complete and verified (or made without
    verification); {} for a recipe without splits."""
    root = Path(root)
    recipe = load_recipe(root / layout.RECIPE_COPY)
    out: dict[str, list[Path]] = {}
    for spec in scene_specs(recipe):
        rec = _read_record(root / layout.RECIPE_SCENES / f"{spec.name}.json")
        folder = root / layout.RECIPE_SCENES / spec.name
        if spec.split and rec and rec["spec"] == _spec_dict(spec) and rec["verified"] and (folder / layout.MANIFEST).is_file():
            out.setdefault(spec.split, []).append(folder)
    return out


def scene_template(folder) -> str | None:
    """The template a made recipe scene folder was generated from (its record's spec), None for a
    folder that is not a recipe scene with a readable record."""
    folder = Path(folder)
    rec = _read_record(folder.parent / f"{folder.name}.json")
    spec = rec.get("spec") if rec else None
    return str(spec["template"]) if isinstance(spec, dict) and "template" in spec else None


def _read_record(path: Path) -> dict | None:
    if not path.is_file():
        return None
    try:
        rec = json.loads(path.read_text())
        return rec if isinstance(rec, dict) and rec.get("version") == RECORD_VERSION else None
    except (OSError, ValueError):
        return None  # a damaged record: the scene is made again (its render resumes)


def _verify_scene(out: Path, mode: str, thresholds: dict[str, float]) -> tuple[bool, dict, list[str]]:
    """(ok, pixels compared per key, failure lines) of ``lfusd verify`` on every rig of a scene."""
    from .data.dataset import open_datasets
    from .truth.verify import verify

    from .truth.verify import record_certificate

    ok, compared, failures = True, {}, []
    for ds in open_datasets(out, "all"):
        views = [ds.rig.centre_view] if mode == "centre" else None
        reports = verify(out, rig=ds.rig_name, views=views, thresholds=thresholds)
        record_certificate(out, reports)  # the scene's manifest carries verify's per-key figures
        for rep in reports.values():
            ok &= rep.ok
            failures += rep.failures()
            for k, n in rep.compared().items():
                compared[k] = compared.get(k, 0) + n
    return ok, compared, failures[:20]


def _certificate(out: Path) -> dict:
    """Per key over a scene's rigs, from its manifest's certificate (where its binding to the
    scene's content holds): pixels compared, worst max, over the limit, ties."""
    from .data.certificate import certified

    try:
        cert = certified(out)  # only figures still bound to the scene's content
    except LfusdError:
        return {}
    keys: dict[str, dict] = {}
    for rig in cert.values():
        for k, e in rig.get("keys", {}).items():
            t = keys.setdefault(k, {"count": 0, "max": 0.0, "over": 0, "ties": 0, "threshold": e["threshold"]})
            t["count"] += e["count"]
            t["max"] = max(t["max"], e["max"])
            t["over"] += e["over"]
            t["ties"] += e["ties"]
    return keys


def make_scene(recipe: Recipe, spec: SceneSpec, root: Path, quiet: bool = True) -> dict:
    """Generate, render, verify and measure one scene; return its record (written by the caller)."""
    from .author.scenes import generate
    from .render.job import render, render_video
    from .camera import Distortion
    from .render.request import RenderRequest

    stage = root / layout.RECIPE_STAGES / f"{spec.name}.usda"
    out = root / layout.RECIPE_SCENES / spec.name
    if not stage.is_file():
        generate(spec.template, stage, spec.seed, frames=spec.frames, rigs=spec.rigs, grid=spec.grid,
                 resolution=spec.resolution, dynamic=spec.dynamic, catalogues=spec.catalogues)
    req = RenderRequest(stage=stage, out=out, rig="all", samples=recipe.samples, device=recipe.device, workers=recipe.workers,
                        executor=recipe.executor, ray_address=recipe.ray_address, quiet=quiet, sensor=recipe.sensor,
                        # the masks need render-video's triangles, the blur key its neighbouring frames
                        materials=recipe.materials and spec.dynamic, shutter=recipe.shutter if spec.dynamic else 0.0,
                        fstop=recipe.lens[0], focus=recipe.lens[1],
                        lens=Distortion(*recipe.distortion) if recipe.distortion else None, lens_seed=recipe.distortion_seed,
                        lens_spread=recipe.distortion_spread)
    if spec.dynamic:
        render_video(req)
    else:
        render(req)
    ok, compared, failures = (True, {}, []) if recipe.verify == "none" else _verify_scene(out, recipe.verify, dict(recipe.thresholds))
    design = disparity_design(stage)
    return {"version": RECORD_VERSION, "spec": _spec_dict(spec), "verified": ok, "verify": recipe.verify,
            "thresholds": dict(recipe.thresholds), **({"disparity_design": design} if design else {}),
            "compared": compared, "failures": failures, "certificate": _certificate(out), "stats": scene_stats(out, recipe.stats_views)}


def disparity_design(stage_path) -> dict | None:
    """The stage's disparity design (customData ``lfusd:disparity`` of a ``things`` stage: shift_px,
    range_px, ...; lfusd.author.scenes.things), kept in the scene's record so that training code
    finds it without opening the stage; None when the stage has none."""
    from pxr import Usd

    from .author.vocabulary import DISPARITY

    stage = Usd.Stage.Open(str(stage_path))
    prim = stage.GetDefaultPrim() if stage else None
    design = prim.GetCustomDataByKey(DISPARITY) if prim else None
    return json.loads(json.dumps(dict(design))) if design else None


def check_recipe_size(recipe: Recipe, root: Path) -> None:
    """Refuse, before anything is generated, a recipe whose scenes not yet made need more disk
    than is free under ``root`` (lfusd.render.request's per-pixel estimate, every rig of a scene
    at the part's largest rig count)."""
    from .render.request import _free_disk, _gb, size_estimate

    views = recipe.grid[0] * recipe.grid[1]
    need = 0.0
    for spec in scene_specs(recipe):
        if (root / layout.RECIPE_SCENES / spec.name).exists():
            continue  # made, or being made: its files are already on the disk
        rigs = [(f"rig_{i:02d}", views, *recipe.resolution) for i in range(spec.rigs)]
        need += size_estimate(rigs, spec.frames, spec.dynamic, 1)[0]
    free = _free_disk(root)
    if free is not None and need > free:
        raise LfusdError(f"the recipe's scenes need about {_gb(need)} of disk ({_gb(free)} free under {root}); "
                         "free space, or lower the recipe's scenes, frames, grid or resolution")


def _check_folder(root: Path, recipe_text: str) -> None:
    """A rerun into ``root`` must use the recipe that made it (same text): lfusd.data.folder.resumable_folder
    with the recipe's copy as the record (a folder without one is a new recipe dataset)."""
    from .data.folder import resumable_folder

    def same_recipe(copy: Path) -> str:
        if copy.read_text() != recipe_text:
            raise LfusdError(f"{root} was made from a different recipe ({copy}); rerun with that recipe or choose a new -o folder")
        return recipe_text

    resumable_folder(root, layout.RECIPE_COPY, "dataset", "recipe dataset", same_recipe, foreign=True)


RUN_SETTINGS = ("executor", "ray_address", "workers", "device")  # how a scene renders, not what: not part of its identity


def make_dataset(recipe_path, root, quiet: bool = True, progress=None, overrides: dict | None = None) -> MakeResult:
    """Make (or finish) the dataset of the recipe at ``recipe_path`` in folder ``root`` and write its card.

    ``progress(index, total, scene, action)`` is called per scene ('skip' or 'make').
    ``overrides``: values of :data:`RUN_SETTINGS` replacing the recipe's (``lfusd bench make --executor ray``)."""
    from dataclasses import replace

    from .data.folder import atomic_write, output_lock

    recipe_path, root = Path(recipe_path), Path(root)
    recipe = load_recipe(recipe_path)
    if overrides:
        unknown = set(overrides) - set(RUN_SETTINGS)
        if unknown:
            raise LfusdError(f"cannot override {', '.join(sorted(unknown))} of a recipe; only {', '.join(RUN_SETTINGS)}")
        recipe = replace(recipe, **overrides)
    text = recipe_path.read_text()
    if root.exists() and not root.is_dir():
        raise LfusdError(f"output {root} is a file; give a folder for the dataset")
    check_recipe_size(recipe, root)
    try:
        root.mkdir(parents=True, exist_ok=True)
    except OSError as e:
        raise LfusdError(f"cannot create {root} ({e.strerror or e}); choose a writable -o folder") from None
    result = MakeResult()
    with output_lock(root):
        from .data import confined

        for name in (layout.RECIPE_COPY, layout.RECIPE_STAGES, layout.RECIPE_SCENES, layout.RECIPE_CARD, layout.RECIPE_CARD_JSON,
                     layout.RECIPE_PLOTS):
            if confined.is_link(root / name):  # lfusd writes there: never through a link planted in the folder
                raise confined.link_error(root / name)
        _check_folder(root, text)
        (root / layout.RECIPE_SCENES).mkdir(exist_ok=True)
        atomic_write(root / layout.RECIPE_COPY, text)
        specs = scene_specs(recipe)
        records = {}
        for i, spec in enumerate(specs):
            result.scenes.append(spec.name)
            path = root / layout.RECIPE_SCENES / f"{spec.name}.json"
            rec = _read_record(path)
            if rec and rec["spec"] == _spec_dict(spec) and rec["verified"] and rec.get("thresholds") == dict(recipe.thresholds) and (root / layout.RECIPE_SCENES / spec.name / layout.MANIFEST).is_file():
                result.skipped.append(spec.name)
                log.info("scene %s: complete and verified, skipped", spec.name)
                if progress:
                    progress(i, len(specs), spec.name, "skip")
                # the card republishes the certificate: only while it is still bound to the scene's files
                rec = {**rec, "certificate": _certificate(root / layout.RECIPE_SCENES / spec.name)}
                records[spec.name] = rec
                continue
            if progress:
                progress(i, len(specs), spec.name, "make")
            rec = make_scene(recipe, spec, root, quiet=quiet)
            atomic_write(path, json.dumps(rec, indent=1) + "\n")  # last: the scene is done
            records[spec.name] = rec
            result.made.append(spec.name)
            if not rec["verified"]:
                result.failed.append(spec.name)
                log.warning("scene %s failed verification: %s", spec.name, rec["failures"][0] if rec["failures"] else "no pixels compared")
        result.card = write_card(root, recipe, specs, records)
    return result


# -- the card ---------------------------------------------------------------------------------

def summarize(recipe: Recipe, specs: list[SceneSpec], records: dict[str, dict]) -> dict:
    """card.json: the recipe, the scene list and the statistics summed over scenes."""
    disp = [0] * (len(DISPARITY_EDGES) - 1)
    flow = [0] * (len(FLOW_EDGES) - 1)
    classes: dict[str, int] = {}
    dmin, dmax, dpx, fpx, pixels = None, None, 0, 0, 0
    scenes = []
    for spec in specs:
        rec = records[spec.name]
        st = rec["stats"]
        pixels += st["pixels"]
        d = st["disparity"]
        disp = [a + b for a, b in zip(disp, d["counts"])]
        dpx += d["pixels"]
        if d["pixels"]:
            dmin = d["min"] if dmin is None else min(dmin, d["min"])
            dmax = d["max"] if dmax is None else max(dmax, d["max"])
        flow = [a + b for a, b in zip(flow, st["flow"]["counts"])]
        fpx += st["flow"]["pixels"]
        for k, n in st["classes"].items():
            classes[k] = classes.get(k, 0) + n
        all_cov = [x for s in st["coverage"].values() for x in s]
        scenes.append({"name": spec.name, "part": spec.part, "split": spec.split, "template": spec.template, "seed": spec.seed, "rigs": spec.rigs,
                       "frames": spec.frames, "dynamic": spec.dynamic, "verified": rec["verified"], "compared": rec["compared"],
                       "certificate": rec.get("certificate") or {},
                       "disparity": [d["min"], d["max"]], "coverage": _coverage_summary(all_cov) if spec.dynamic else None})
    return {
        "name": recipe.name,
        "recipe": json.loads(json.dumps(asdict(recipe))),
        "scenes": scenes,
        "stats_views": recipe.stats_views,
        "pixels": pixels,
        "disparity": {"pixels": dpx, "min": dmin, "max": dmax, "edges": [str(e) if e == float("inf") else e for e in DISPARITY_EDGES], "counts": disp},
        "flow": {"pixels": fpx, "edges": [str(e) if e == float("inf") else e for e in FLOW_EDGES], "counts": flow},
        "coverage": _coverage_summary([x for s in specs if s.dynamic for v in records[s.name]["stats"]["coverage"].values() for x in v]),
        "classes": dict(sorted(classes.items(), key=lambda kv: -kv[1])),
        "verified": all(records[s.name]["verified"] for s in specs),
    }


def _plots(root: Path, card: dict, records: dict, specs: list[SceneSpec]) -> list[str]:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    folder = root / layout.RECIPE_PLOTS
    folder.mkdir(exist_ok=True)
    names = []

    def bars(name, edges, counts, xlabel, title):
        fig, ax = plt.subplots(figsize=(6, 3.2))
        labels = [f"{edges[i]:g}" for i in range(len(counts))]
        ax.bar(range(len(counts)), counts, color="#4878a8")
        ax.set_xticks(range(len(counts)), labels, rotation=45, fontsize=7)
        ax.set_xlabel(xlabel)
        ax.set_ylabel("pixels")
        if any(counts):
            ax.set_yscale("log")
        ax.set_title(title, fontsize=9)
        fig.tight_layout()
        fig.savefig(folder / name, dpi=80)
        plt.close(fig)
        names.append(name)

    d, f = card["disparity"], card["flow"]
    bars("disparity.png", DISPARITY_EDGES, d["counts"], "disparity (px per baseline step), bin from", f"disparity, {d['pixels']} px")
    bars("flow.png", FLOW_EDGES, f["counts"], "|flow_fwd| (px), bin from", f"forward flow magnitude, {f['pixels']} px")
    fig, ax = plt.subplots(figsize=(6, 3.2))
    for s in specs:
        for key, series in records[s.name]["stats"]["coverage"].items():
            if series:
                ax.plot(range(1, len(series) + 1), [100 * x for x in series], lw=1, label=f"{s.name} {key}")
    ax.axhline(100 * GOAL_COVERAGE, color="k", ls="--", lw=0.8)
    ax.set_xlabel("frame pair")
    ax.set_ylabel("moving pixels (%)")
    ax.set_title("motion coverage per view and frame", fontsize=9)
    labelled = [ln for ln in ax.lines if not ln.get_label().startswith("_")]
    if 0 < len(labelled) <= 8:
        ax.legend(fontsize=6)
    fig.tight_layout()
    fig.savefig(folder / "coverage.png", dpi=80)
    plt.close(fig)
    names.append("coverage.png")
    fig, ax = plt.subplots(figsize=(6, 3.2))
    cls = card["classes"]
    ax.barh(list(cls)[::-1], list(cls.values())[::-1], color="#6a9f58")
    ax.set_xscale("log" if cls else "linear")
    ax.set_xlabel("pixels")
    ax.set_title("class frequencies", fontsize=9)
    ax.tick_params(labelsize=7)
    fig.tight_layout()
    fig.savefig(folder / "classes.png", dpi=80)
    plt.close(fig)
    names.append("classes.png")
    return names


def effects_text(r: dict) -> str:
    """The camera effects of a recipe (card.json's ``recipe``) in words: what the card says the dataset has."""
    on = []
    if r.get("shutter"):
        on.append(f"motion blur over {r['shutter']:g} of a frame (key blur, dynamic scenes)")
    if (r.get("lens") or (0, 0))[0]:
        on.append(f"defocus at f/{r['lens'][0]:g} focused at {r['lens'][1]:g} m (key coc)")
    if r.get("sensor"):
        sn = r["sensor"]
        on.append(f"sensor noise at ISO {sn['iso']:g}, seed {sn['seed']}" + (f", JPEG {sn['jpeg']}" if sn["jpeg"] else "") + " (key rgb_noisy)")
    if r.get("materials"):
        on.append("material masks and depth_behind (dynamic scenes)")
    if any(r.get("distortion") or ()):
        k = ", ".join(f"{c:g}" for c in r["distortion"])
        seed = f", each view's drawn with seed {r['distortion_seed']} and spread {r['distortion_spread']:g}" if r.get("distortion_seed") is not None else ""
        on.append(f"lens distortion k1, k2, p1, p2, k3 = {k}{seed} (every key in distorted pixels)")
    return "; ".join(on) if on else "none (sharp, noiseless pinhole images)"


def card_markdown(card: dict, plots: list[str]) -> str:
    r = card["recipe"]
    lines = [f"# Dataset card: {card['name']}", "",
             f"{len(card['scenes'])} scenes, {r['grid'][0]}x{r['grid'][1]} views per rig at {r['resolution'][0]}x{r['resolution'][1]}, "
             f"{r['samples']} samples; verification: {r['verify']} ({'all passed' if card['verified'] else 'SOME FAILED'}"
             f"{', limits replaced: ' + ', '.join(f'{k} {v:g}' for k, v in r['thresholds']) if r['thresholds'] else ''}). "
             f"Statistics over the {card['stats_views']} view(s) of every rig and frame: {card['pixels']} pixels.", "",
             f"Camera effects: {effects_text(r)}.", ""]
    splits = {}
    for s in card["scenes"]:
        if s.get("split"):
            splits.setdefault(s["split"], []).append(s)
    if splits:
        lines += ["Splits (disjoint scenes): " + "; ".join(
            f"{k} {len(v)} scenes ({', '.join(sorted({x['template'] for x in v}))})" for k, v in splits.items())
            + (f"; held out for test only: {', '.join(r['held_out'])}" if r.get("held_out") else "") + ".", ""]
    lines += ["## Scenes", "", "| scene | part | template | seed | rigs | frames | verified | px compared | disparity (px) | motion: frames moving / >= 5 % / mean |",
             "|---|---|---|---|---|---|---|---|---|---|"]
    for s in card["scenes"]:
        cov = s["coverage"]
        c = f"{cov['any']:.0%} / {cov['goal']:.0%} / {cov['mean']:.1%} of {cov['frames']}" if cov else "static"
        dr = f"{s['disparity'][0]:.3g}-{s['disparity'][1]:.3g}" if s["disparity"][0] is not None else "-"
        lines.append(f"| {s['name']} | {s['part']} | {s['template']} | {s['seed']} | {s['rigs']} | {s['frames']} | "
                     f"{'yes' if s['verified'] else 'NO'} | {sum(s['compared'].values())} | {dr} | {c} |")
    cert: dict[str, dict] = {}
    for s in card["scenes"]:
        for k, e in (s.get("certificate") or {}).items():
            t = cert.setdefault(k, {"count": 0, "max": 0.0, "over": 0, "ties": 0, "threshold": e["threshold"]})
            t["count"], t["max"] = t["count"] + e["count"], max(t["max"], e["max"])
            t["over"], t["ties"] = t["over"] + e["over"], t["ties"] + e["ties"]
    if cert:
        lines += ["", "## Verification certificate", "",
                  "Every foreground pixel compared with independently traced geometry (`lfusd verify`; per scene in its manifest.json):", "",
                  "| key | pixels compared | max error | limit | over the limit | ties |", "|---|---|---|---|---|---|"]
        lines += [f"| {k} | {e['count']} | {e['max']:.3g} | {e['threshold']:g} | {e['over']} | {e['ties']} |" for k, e in cert.items()]
    d, f, cov = card["disparity"], card["flow"], card["coverage"]
    lines += ["", "## Statistics", ""]
    if d["pixels"]:
        lines.append(f"- disparity: {d['min']:.4g} to {d['max']:.4g} px per baseline step over {d['pixels']} pixels with a surface")
    lines.append(f"- forward flow: {f['pixels']} valid pixels; |flow| > {MOVING} px on {sum(f['counts'][1:])}")
    lines.append(f"- motion coverage (dynamic scenes): moving pixels in {cov['any']:.0%} of {cov['frames']} view-frames, "
                 f">= {GOAL_COVERAGE:.0%} of the view in {cov['goal']:.0%}, mean {cov['mean']:.1%}")
    total = sum(card["classes"].values()) or 1
    lines.append("- classes: " + ", ".join(f"{k} {100 * n / total:.1f} %" for k, n in card["classes"].items()))
    lines += ["", "## Plots", ""] + [f"![{p}]({layout.RECIPE_PLOTS}/{p})" for p in plots]
    return "\n".join(lines) + "\n"


def write_card(root: Path, recipe: Recipe, specs: list[SceneSpec], records: dict[str, dict]) -> dict:
    """Write card.json, CARD.md and plots/*.png; return the card."""
    from .data.folder import atomic_write

    card = summarize(recipe, specs, records)
    plots = _plots(root, card, records, specs)
    atomic_write(root / layout.RECIPE_CARD_JSON, json.dumps(card, indent=1) + "\n")
    atomic_write(root / layout.RECIPE_CARD, card_markdown(card, plots))
    return card

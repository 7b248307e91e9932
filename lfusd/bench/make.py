"""Frozen benchmark definitions and ``lfusd bench make NAME -o DIR``.

A definition is two files in ``lfusd/bench/definitions/``: ``<name>.toml``, a dataset recipe
(lfusd.recipe) whose parts are exactly ``train``, ``val`` and ``test`` (dynamic videos; no two
scenes share a template and seed, so the splits hold disjoint scenes), and
``<name>.digests.json``, the sha256 of every scene's generated stage (``.usda``). The stages are
generated first and compared with the digests: a generator that changed since the benchmark was
frozen is refused before anything renders (``scripts/bench_freeze.py NAME`` re-freezes: a new
benchmark version).

DIR gets (names in lfusd.layout):

    DIR/bench.json      the definition's name and digest, the splits, frames and views; a rerun must match it
    DIR/recipe.toml     the definition's recipe
    DIR/render/         `lfusd dataset make`'s folder of every scene (test ground truth included: never publish it)
    DIR/public/         train/<scene>/ and val/<scene>/: lfusd datasets with ground truth;
                        test/<scene>/: cameras.json and rgb/<frame>_<row>_<col>.png only; CARD.md (train and val statistics)
    DIR/gt/             <scene>/: the test scenes' lfusd datasets; digests.json: sha256 of every file under gt/
    DIR/CARD.md         the card of every scene

Files are hard links into render/ where the file system has them. A rerun resumes: rendered
scenes are skipped (lfusd.recipe), public/ and gt/ are written again from render/.
"""

from __future__ import annotations

import hashlib
import json
import logging
import os
import tomllib
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from .. import layout
from ..errors import LfusdError
from ..files import sha256_of

log = logging.getLogger(__name__)

DEFINITIONS = Path(__file__).resolve().parent / "definitions"
SPLITS = ("train", "val", "test")
FORMAT = "lfusd-bench"
RECORD_VERSION = 1
DISPARITY_MARGIN = 0.1  # cameras.json's disparity range: the true range widened by this fraction (at least 0.05 px per side)
_SKIP = {layout.LOCK, layout.LOGS, layout.SCRATCH}  # a scene folder's run files: not part of the dataset


@dataclass(frozen=True)
class Definition:
    name: str
    path: Path
    text: str  # the recipe's TOML
    recipe: object  # lfusd.recipe.Recipe
    specs: tuple  # lfusd.recipe.SceneSpec of every scene, in order
    digests: dict  # scene -> sha256 of its stage
    digest: str  # sha256 of the two files: the definition's identity

    def split(self, name: str) -> list:
        return [s for s in self.specs if s.part == name]


def definition_names() -> list[str]:
    return sorted(p.stem for p in DEFINITIONS.glob("*.toml"))


def load_definition(name: str) -> Definition:
    """The frozen definition ``name`` (``lfusd/bench/definitions/<name>.toml`` and its digests)."""
    from ..recipe import parse_recipe, scene_specs

    names = definition_names()
    if name not in names:
        raise LfusdError(f"unknown benchmark {name!r}; use one of {', '.join(names)}")
    path = DEFINITIONS / f"{name}.toml"
    text = path.read_text()
    recipe = parse_recipe(tomllib.loads(text), str(path))
    if any(recipe.distortion):  # what lfusd.data.folder.require_pinhole refuses, before any scene is rendered
        raise LfusdError(f"benchmark {path}: dataset.lens renders distorted scenes, and a benchmark needs pinhole cameras (its "
                         "cameras.json carries K alone, its baselines and scoring compute with K alone); remove dataset.lens")
    parts = [p.name for p in recipe.parts]
    if sorted(parts) != sorted(SPLITS) or not all(p.dynamic for p in recipe.parts):
        raise LfusdError(f"benchmark {path}: needs exactly the dynamic parts {', '.join(SPLITS)}, got {', '.join(parts)}; fix the definition")
    specs = scene_specs(recipe)
    seen: dict[tuple[str, int], str] = {}
    for s in specs:
        if (s.template, s.seed) in seen:
            raise LfusdError(f"benchmark {path}: scenes {seen[(s.template, s.seed)]} and {s.name} are the same scene; give the parts disjoint seeds")
        seen[(s.template, s.seed)] = s.name
    dpath = DEFINITIONS / f"{name}.digests.json"
    try:
        dtext = dpath.read_text()
        digests = json.loads(dtext)["stages"]
    except (OSError, ValueError, KeyError, TypeError):
        raise LfusdError(f"benchmark {name} has no readable {dpath.name}; freeze it with `python scripts/bench_freeze.py {name}`") from None
    digest = hashlib.sha256(text.encode() + b"\0" + dtext.encode()).hexdigest()
    return Definition(name, path, text, recipe, tuple(specs), digests, digest)


def generate_stage(d: Definition, spec, folder: Path) -> Path:
    """Generate ``spec``'s stage in ``folder`` (as lfusd.recipe.make_scene would) unless it is there; its path."""
    from ..author.scenes import generate

    stage = folder / f"{spec.name}.usda"
    if not stage.is_file():
        generate(spec.template, stage, spec.seed, frames=spec.frames, rigs=spec.rigs, grid=spec.grid,
                 resolution=spec.resolution, dynamic=spec.dynamic, catalogues=spec.catalogues)
    return stage


def stage_digests(d: Definition, folder: Path) -> dict[str, str]:
    """sha256 of every scene's stage of ``d``, generated in ``folder`` (what `bench_freeze.py` records)."""
    folder.mkdir(parents=True, exist_ok=True)
    return {s.name: sha256_of(generate_stage(d, s, folder)) for s in d.specs}


def check_stages(d: Definition, folder: Path) -> None:
    """Generate the stages into ``folder`` and refuse any whose digest differs from the frozen one."""
    for s in d.specs:
        want = d.digests.get(s.name)
        got = sha256_of(generate_stage(d, s, folder))
        if want != got:
            raise LfusdError(f"stage {s.name} of benchmark {d.name} differs from its frozen digest ({got[:12]} != {str(want)[:12]}): "
                             f"the scene generators changed; use the lfusd release that froze it, or re-freeze with "
                             f"`python scripts/bench_freeze.py {d.name}` (a new benchmark version)")


# -- the folder -------------------------------------------------------------------------------

def read_record(root: Path) -> dict:
    """DIR/bench.json of a benchmark folder; one-line LfusdError when it is not one."""
    path = Path(root) / layout.BENCH_RECORD
    try:
        rec = json.loads(path.read_text())
    except (OSError, ValueError):
        raise LfusdError(f"{root} is not a benchmark folder (no readable {layout.BENCH_RECORD}); give the -o folder of `lfusd bench make`") from None
    if not isinstance(rec, dict) or rec.get("format") != FORMAT:
        raise LfusdError(f"{path} was not written by `lfusd bench make`; give the -o folder of `lfusd bench make`")
    if not rec.get("complete"):
        raise LfusdError(f"benchmark {root} is not complete; rerun `lfusd bench make {rec.get('name', 'NAME')} -o {root}` to finish it")
    return rec


def _link_tree(src: Path, dst: Path) -> None:
    """Hard-link (or copy) every file under ``src`` to ``dst``, leaving out the run files."""
    from ..data.formats import link_or_copy

    for dirpath, dirnames, filenames in os.walk(src):
        here = Path(dirpath)
        dirnames[:] = sorted(n for n in dirnames if n not in _SKIP and not n.startswith("."))
        out = dst / here.relative_to(src)
        out.mkdir(parents=True, exist_ok=True)
        for n in sorted(filenames):
            if n in _SKIP or n.startswith("."):
                continue
            q = out / n
            if q.exists() and os.path.samefile(here / n, q):
                continue
            link_or_copy(here / n, q)


def disparity_range(ds) -> list[float]:
    """The true disparity range of a scene over every frame and view, widened by DISPARITY_MARGIN (the
    sweep range a method may assume, as the HCI benchmark gives disp_min / disp_max)."""
    lo, hi = np.inf, -np.inf
    for f in ds.frames:
        for v in ds.views:
            depth = np.asarray(ds.read(f, v, "depth"))
            d = np.asarray(ds.read(f, v, "disparity"))[np.isfinite(depth)]
            if d.size:
                lo, hi = min(lo, float(d.min())), max(hi, float(d.max()))
    if not np.isfinite(lo):
        lo, hi = 0.0, 1.0
    pad = max(DISPARITY_MARGIN * (hi - lo), 0.05)
    return [lo - pad, hi + pad]


def cameras(ds) -> dict:
    """cameras.json of a scene: what a method gets besides the images (a pinhole's: K, poses, offsets)."""
    from ..data.folder import require_pinhole
    from ..layout import view_key

    require_pinhole(ds, "a benchmark's cameras.json (K alone)", "make the benchmark from a definition without dataset.lens")
    r = ds.rig
    return {
        "grid": [r.rows, r.cols], "resolution": [r.width, r.height], "baseline": ds.baseline, "centre_view": list(r.centre_view),
        "frames": list(ds.frames), "scored_frames": list(ds.frames[:-1]),
        "views": [list(v) for v in ds.views],
        "offsets": {view_key(v): list(r.offsets(tuple(v))) for v in ds.views},
        "intrinsics": np.asarray(ds.intrinsics(ds.views[0]), np.float64).tolist(),
        "cam_to_world": {str(f): {view_key(v): ds.cam_to_world(f, tuple(v)).tolist() for v in ds.views} for f in ds.frames},
        "disparity_range": disparity_range(ds),
    }


def _publish_test(scene_dir: Path, out: Path) -> None:
    from ..data.dataset import Dataset
    from ..data.formats import encode_png
    from ..files import atomic_write

    ds = Dataset(scene_dir)
    (out / layout.BENCH_RGB).mkdir(parents=True, exist_ok=True)
    for f in ds.frames:
        for v in ds.views:
            path = out / layout.BENCH_RGB / f"{layout.bench_name(f, tuple(v))}.png"
            if not path.is_file():
                atomic_write(path, encode_png(np.asarray(ds.read(f, tuple(v), "rgb"))))
    atomic_write(out / layout.BENCH_CAMERAS, json.dumps(cameras(ds), indent=1) + "\n")


def gt_digests(gt: Path) -> dict[str, str]:
    """sha256 of every file under ``gt`` but digests.json, by path relative to it."""
    out = {}
    for p in sorted(gt.rglob("*")):
        if p.is_file() and p.name != layout.BENCH_DIGESTS:
            out[p.relative_to(gt).as_posix()] = sha256_of(p)
    return out


def check_gt(root: Path, rec: dict) -> None:
    """Refuse a gt/ whose digests.json or any file it lists differs from what `bench make` wrote."""
    gt = Path(root) / layout.BENCH_GT
    path = gt / layout.BENCH_DIGESTS
    if not path.is_file() or sha256_of(path) != rec.get("gt_digests"):
        raise LfusdError(f"{path} is missing or differs from the one `lfusd bench make` wrote; rerun `lfusd bench make {rec['name']} -o {root}`")
    listed = json.loads(path.read_text())
    for rel, want in listed.items():
        p = gt / rel
        if not p.is_file() or sha256_of(p) != want:
            raise LfusdError(f"{p}: test ground truth {'missing' if not p.is_file() else 'changed'} since `lfusd bench make` wrote it; "
                             f"rerun `lfusd bench make {rec['name']} -o {root}` to restore it")


@dataclass
class BenchResult:
    root: Path
    made: list[str] = field(default_factory=list)
    skipped: list[str] = field(default_factory=list)
    record: dict = field(default_factory=dict)


def make_bench(name: str, root, quiet: bool = True, progress=None, executor: str | None = None, ray_address: str | None = None,
               workers: int | None = None, device: str | None = None) -> BenchResult:
    """Make (or finish) benchmark ``name`` in folder ``root``; see the module docstring.

    ``executor``, ``ray_address``, ``workers``, ``device`` replace the definition's render settings
    (they change how, not what, it renders). ``progress(i, n, scene, action)`` as lfusd.recipe's."""
    from ..data.folder import output_lock, resumable_folder
    from ..files import atomic_write
    from ..recipe import _read_record, make_dataset, write_card

    d = load_definition(name)
    root = Path(root)

    def same(path: Path) -> dict:
        try:
            rec = json.loads(path.read_text())
        except (OSError, ValueError):
            rec = None
        if not isinstance(rec, dict) or rec.get("format") != FORMAT:
            raise LfusdError(f"{path} was not written by `lfusd bench make`; choose an empty or new -o folder")
        if rec.get("definition") != d.digest:
            raise LfusdError(f"{root} was made from another benchmark definition ({rec.get('name')}, {str(rec.get('definition'))[:12]}); "
                             "choose a new -o folder")
        return rec

    existed = root.exists()
    fresh = resumable_folder(root, layout.BENCH_RECORD, "benchmark", "lfusd benchmark", same) is None  # absent or empty
    try:
        root.mkdir(parents=True, exist_ok=True)
    except OSError as e:
        raise LfusdError(f"cannot create {root} ({e.strerror or e}); choose a writable -o folder") from None
    result = BenchResult(root)
    with output_lock(root):
        rec = {"format": FORMAT, "version": RECORD_VERSION, "name": d.name, "definition": d.digest, "complete": False}
        render = root / layout.BENCH_RENDER
        try:
            atomic_write(root / layout.BENCH_RECORD, json.dumps(rec, indent=1) + "\n")
            atomic_write(root / layout.BENCH_RECIPE, d.text)
            check_stages(d, render / layout.RECIPE_STAGES)
        except BaseException:
            if fresh:  # a refused (or stopped) first run leaves the folder as it found it
                _undo(root, existed)
            raise
        overrides = {k: v for k, v in (("executor", executor), ("ray_address", ray_address), ("workers", workers), ("device", device)) if v is not None}
        made = make_dataset(root / layout.BENCH_RECIPE, render, quiet=quiet, progress=progress, overrides=overrides)
        result.made, result.skipped = made.made, made.skipped
        if made.failed:
            raise LfusdError(f"scenes {', '.join(made.failed)} failed verification (see {render / layout.RECIPE_SCENES}/<scene>.json); "
                             "the benchmark is not published")
        scenes = render / layout.RECIPE_SCENES
        public, gt = root / layout.BENCH_PUBLIC, root / layout.BENCH_GT
        for split in ("train", "val"):
            for s in d.split(split):
                _link_tree(scenes / s.name, public / split / s.name)
        for s in d.split("test"):
            _publish_test(scenes / s.name, public / "test" / s.name)
            _link_tree(scenes / s.name, gt / s.name)
        digests = gt_digests(gt)
        atomic_write(gt / layout.BENCH_DIGESTS, json.dumps(digests, indent=1) + "\n")
        records = {s.name: _read_record(scenes / f"{s.name}.json") for s in d.specs}
        shown = [s for s in d.specs if s.part != "test"]
        write_card(public, d.recipe, shown, {s.name: records[s.name] for s in shown})
        splits = {p: [s.name for s in d.split(p)] for p in SPLITS}
        header = _card_header(d, splits)
        (public / layout.BENCH_CARD).write_text(header + "Statistics below: train and val only.\n\n" + (public / layout.RECIPE_CARD).read_text())
        (root / layout.BENCH_CARD).write_text(header + "Statistics below: every scene, test included (do not publish this file).\n\n"
                                              + (render / layout.RECIPE_CARD).read_text().replace("](plots/", "](render/plots/"))
        from ..data.dataset import Dataset

        ds = Dataset(scenes / d.split("test")[0].name)
        rec |= {"complete": True, "splits": splits, "grid": list(d.recipe.grid), "resolution": list(d.recipe.resolution),
                "frames": {s.name: list(Dataset(scenes / s.name).frames) for s in d.split("test")},
                "views": [list(v) for v in ds.views], "gt_digests": sha256_of(gt / layout.BENCH_DIGESTS)}
        atomic_write(root / layout.BENCH_RECORD, json.dumps(rec, indent=1) + "\n")
        result.record = rec
    return result


def _undo(root: Path, existed: bool) -> None:
    """Remove what a first run wrote before it rendered anything: the record, the recipe and the stages."""
    import shutil

    for name in (layout.BENCH_RECORD, layout.BENCH_RECIPE):
        (root / name).unlink(missing_ok=True)
    shutil.rmtree(root / layout.BENCH_RENDER, ignore_errors=True)
    if not existed:
        (root / layout.LOCK).unlink(missing_ok=True)
        try:
            root.rmdir()
        except OSError:
            pass  # something else appeared there meanwhile: left alone


def _card_header(d: Definition, splits: dict) -> str:
    r = d.recipe
    lines = [f"# Benchmark card: lfusd bench {d.name}", "",
             f"Light-field video scene-flow benchmark `{d.name}` (definition {d.digest[:12]}): {r.grid[0]}x{r.grid[1]} views at "
             f"{r.resolution[0]}x{r.resolution[1]}, {r.samples} samples per pixel. Splits of disjoint scenes (template and seed):", "",
             "| split | scenes | ground truth published |", "|---|---|---|"]
    for p in SPLITS:
        lines.append(f"| {p} | {', '.join(splits[p])} | {'no (rgb and cameras only; scored by `lfusd bench score`)' if p == 'test' else 'yes'} |")
    lines += ["", "Submission format and metrics: the lfusd docs, commands/bench.md.", "", ""]
    return "\n".join(lines)

"""File and folder names of an lfusd dataset: the one place that spells them.

    OUT/manifest.json                 format, dataset id, stage files and hashes, rigs, frames, complete frames, settings, versions
    OUT/.lock                         held (flock) by the one run writing the folder
    OUT/logs/                         Blender's output of each worker
    OUT/objects.json                  class table and instance table (id -> prim path, label)
    OUT/<rig>/f000001/frame.json      per-view cam_to_world and per-object world poses
    OUT/<rig>/f000001/00_00/          one folder per view (row 00, col 00), format version 2:
        rgb.exr                       the beauty render (linear half RGB); rgb.png instead when only `rgb` is asked for
        gt.exr                        depth, normal, instance (lfusd.data.store)
        motion.exr                    the motion keys (render-video, ``lfusd derive``)
        passes.exr                    Blender's raw passes: removed once the keys above are written and
                                      checked, kept with ``--keep-raw``
        geometry.npz                  (render-video) the frame's world triangles as Blender rendered them,
                                      for exact occlusion; a raw file like passes.exr, removed with it
        view.json                     the completion record: size and sha256 of each file (lfusd.data.integrity)

Format version 1 (lfusd before the storage format, still read by ``Dataset``): rgb.png, rgb.exr,
passes.exr, motion.npz per view. Which key lives in which file is in :mod:`lfusd.keys`.
"""

from __future__ import annotations

from pathlib import Path

FORMAT = "lfusd-dataset"  # manifest["format"]
FORMAT_VERSION = 2  # 1: rgb.png, rgb.exr, passes.exr, motion.npz per view; 2: see the module docstring

# The most frames one dataset holds (manifest["frames"]): a 1-100000000 range is a typo, refused up
# front instead of exhausting the memory that lists of its frames take.
MAX_FRAMES = 1_000_000

MANIFEST = "manifest.json"
OBJECTS = "objects.json"
FRAME_META = "frame.json"
LOGS = "logs"  # Blender's output, one file per worker
SCRATCH = ".scratch"  # workers' temporary files
LOCK = ".lock"  # one writer per dataset folder: the pid and command of the run holding it
# What lfusd writes at the top of OUT, besides one folder per rig (manifest["rigs"]): the only
# entries `--overwrite` removes.
OWN_ENTRIES = (OBJECTS, LOGS, SCRATCH)

# Per-view files.
RGB_PNG = "rgb.png"
RGB_EXR = "rgb.exr"
PASSES_EXR = "passes.exr"
GEOMETRY = "geometry.npz"  # the frame's triangles as rendered (render-video): raw, removed with passes.exr
GT_FILE = "gt.exr"
MOTION_FILE = "motion.exr"
VIEW_RECORD = "view.json"  # written last: the view is complete only if its files match it
VIEW_FILES = (RGB_EXR, RGB_PNG, GT_FILE, MOTION_FILE, PASSES_EXR, GEOMETRY, VIEW_RECORD)
MOTION_FILE_V1 = "motion.npz"  # format version 1's motion keys (np.savez)
VIEW_FILES_V1 = (RGB_PNG, RGB_EXR, PASSES_EXR, MOTION_FILE_V1, VIEW_RECORD)


def view_key(view: tuple[int, int]) -> str:
    """The folder name of a view and its key in frame.json: ``04_04`` for (row 4, col 4)."""
    return f"{view[0]:02d}_{view[1]:02d}"


def frame_name(frame: int) -> str:
    """The name of one frame's folder: ``f000001``."""
    return f"f{frame:06d}"


def frame_dir(root: Path, rig: str, frame: int) -> Path:
    """The folder of one frame of one rig: ``OUT/<rig>/f000001``."""
    return Path(root) / rig / frame_name(frame)


# A rig study's folder (`lfusd rig-study -o STUDY`): its own files, and the dataset of its renders.
STUDY_RECORD = "study.json"  # the study's settings; a rerun must match them (resume)
STUDY_RENDER_LAYER = "render.usda"  # layer over the stage: one union rig of distinct cameras per position
STUDY_CANDIDATES_LAYER = "candidates.usda"  # layer over the stage: every candidate as an lfusd rig
STUDY_RENDERS = "renders"  # the lfusd dataset of the union rigs
STUDY_SCORES = "scores"  # one <candidate>.json per scored candidate (what makes a rerun skip it)
STUDY_REPORT = "report.md"
STUDY_HEATMAPS = "heatmaps"  # one <arrangement>.png of per-view redundancy over the grid
STUDY_PLOT = "score_vs_baseline.png"

# A recipe's dataset folder (`lfusd dataset make RECIPE.toml -o DIR`, lfusd.recipe).
RECIPE_COPY = "recipe.toml"  # the recipe it was made from; a rerun must match it scene by scene
RECIPE_STAGES = "stages"  # one <scene>.usda (and textures/) per generated scene
RECIPE_SCENES = "scenes"  # one lfusd dataset folder per scene, and its record <scene>.json
RECIPE_CARD = "CARD.md"
RECIPE_CARD_JSON = "card.json"
RECIPE_PLOTS = "plots"  # the card's PNG figures

# A benchmark folder (`lfusd bench make NAME -o DIR`, lfusd.bench).
BENCH_RECORD = "bench.json"  # the definition it was made from (name, digest, splits); a rerun must match it
BENCH_RECIPE = "recipe.toml"  # the definition's recipe, as `lfusd dataset make` reads it
BENCH_RENDER = "render"  # the recipe's dataset (every scene, test ground truth included): never published
BENCH_PUBLIC = "public"  # what is published: train/ and val/ with ground truth, test/ with rgb and cameras only
BENCH_GT = "gt"  # the test scenes' ground truth (lfusd datasets) and BENCH_DIGESTS
BENCH_DIGESTS = "digests.json"  # sha256 of every file under gt/, checked by `lfusd bench score`
BENCH_CARD = "CARD.md"
BENCH_CAMERAS = "cameras.json"  # a public test scene's rig, intrinsics, poses and disparity range
BENCH_RGB = "rgb"  # a public test scene's images, one PNG per frame and view


def bench_name(frame: int, view: tuple[int, int]) -> str:
    """The stem of a benchmark image or submission file: ``0001_04_04`` (frame 1, row 4, col 4)."""
    return f"{frame:04d}_{view[0]:02d}_{view[1]:02d}"

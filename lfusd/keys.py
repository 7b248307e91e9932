"""The ground-truth keys of an lfusd dataset: the one registry of what each key is.

Every key readable with ``Dataset.read(frame, view, key)`` has one :class:`Key` in :data:`KEYS`:
its dtype, its shape after (H, W), its unit and meaning, the per-view file it is stored in or
computed from, the stage that produces it and, where :mod:`lfusd.truth.verify` checks it, its
accuracy. The reader, the motion derivation, the verifier, the PyTorch dataset, the exporters and
docs/CONVENTIONS.md (:func:`markdown_table`) all take their key lists from here.

Adding a key: one row in :data:`_TABLE`, the code that computes it (a raw pass in
``lfusd.data.passes.read_raw``, a derived static key in ``lfusd.data.passes.DERIVED``, a motion
key in ``lfusd.truth.motion.derive_motion``) and a test; regenerate the table in
docs/CONVENTIONS.md with ``python -c "import lfusd.keys as k; print(k.markdown_table())"``.
"""

from __future__ import annotations

from dataclasses import dataclass

from .errors import LfusdError

# Depths at or beyond this are background: Blender writes 1e10 where no surface is hit.
BACKGROUND_DEPTH = 1.0e9

# Stages that produce keys.
IMAGE = "image"  # the beauty render
RAW = "raw pass"  # Blender's data passes, converted to the conventions on read
STATIC = "derived static"  # computed on read from one view's raw passes and the metadata
MOTION = "derived motion"  # derived from frames t-1, t, t+1 (lfusd.truth.motion), stored in motion.npz
STAGES = (IMAGE, RAW, STATIC, MOTION)

# Units of the verification accuracies, as lfusd.truth.verify reports them.
_ACCURACY_UNITS = {"rel": "relative", "px": "px", "m": "m", "frac": "of pixels disagree"}  # for markdown_table


@dataclass(frozen=True)
class Key:
    """One ground-truth key (see the module docstring)."""

    name: str
    dtype: str  # NumPy dtype name of the array Dataset.read returns
    shape: tuple[int, ...]  # shape after (H, W)
    unit: str
    meaning: str
    file: str  # the per-view file (lfusd.layout) it is stored in or computed from
    stage: str  # one of STAGES
    step: int = 0  # +1 / -1: describes the motion to frame t+1 / t-1 and is defined only where that frame exists
    accuracy: float | None = None  # verification limit on the p99 error (lfusd.truth.verify)
    accuracy_unit: str | None = None  # 'rel', 'px', 'm' or 'frac'

    def full_shape(self, height: int, width: int) -> tuple[int, ...]:
        """The array shape of this key in an image of ``height`` x ``width`` pixels."""
        return (height, width, *self.shape)


_TABLE = (
    Key("rgb", "uint8", (3,), "sRGB", "the rendered image, 8-bit sRGB", "rgb.png", IMAGE),
    Key("rgb_linear", "float32", (3,), "linear RGB", "the rendered image, linear (scene-referred) RGB", "rgb.exr", IMAGE),
    Key("depth", "float32", (), "m", "planar z-depth along the optical axis; `inf` where no surface", "passes.exr", RAW,
        accuracy=1e-4, accuracy_unit="rel"),
    Key("normal", "float32", (3,), "unitless", "unit surface normal, world frame; NaN where no surface", "passes.exr", RAW),
    Key("position", "float32", (3,), "m", "world position of the surface seen at the pixel centre; NaN where no surface", "passes.exr", RAW),
    Key("instance", "int32", (), "id", "0 = background, otherwise an id listed in the object table", "passes.exr", RAW,
        accuracy=1e-3, accuracy_unit="frac"),
    Key("vector", "float32", (4,), "px", "Blender's raw vector pass: X, Y = previous - current, Z, W = current - next (raster pixels, y up)",
        "passes.exr", RAW),
    Key("next_position", "float32", (3,), "m", "world position at t+1 of the surface point seen at t; NaN where unknown (render-video)",
        "passes.exr", RAW),
    Key("prev_position", "float32", (3,), "m", "world position at t-1 of the surface point seen at t; NaN where unknown (render-video)",
        "passes.exr", RAW),
    Key("semantic", "int32", (), "id", "class id listed in the class table (0 = unlabelled)", "passes.exr", STATIC),
    Key("disparity", "float32", (), "px", "pixels per unit baseline step, d = f_px * b / z (planar, parallel rigs); 0 where no surface",
        "passes.exr", STATIC),
    Key("depth_euclidean", "float32", (), "m",
        "distance along the pixel's ray from the camera centre to the surface, depth * ||K^-1 [u, v, 1]||; `inf` where no surface",
        "passes.exr", STATIC),
    Key("flow_fwd", "float32", (2,), "px", "(du, dv): the point at (u, v) in frame t is at (u+du, v+dv) in t+1", "motion.npz", MOTION,
        step=1, accuracy=0.05, accuracy_unit="px"),
    Key("flow_bwd", "float32", (2,), "px", "(du, dv): the point at (u, v) in frame t is at (u+du, v+dv) in t-1", "motion.npz", MOTION,
        step=-1, accuracy=0.05, accuracy_unit="px"),
    Key("scene_flow", "float32", (3,), "m", "world-frame displacement of the surface point seen at (u, v), t -> t+1", "motion.npz", MOTION,
        step=1, accuracy=1e-3, accuracy_unit="m"),
    Key("disparity_change", "float32", (), "px", "disparity of that point at t+1 minus its disparity at t", "motion.npz", MOTION,
        step=1, accuracy=0.05, accuracy_unit="px"),
    Key("valid_fwd", "bool", (), "mask", "where the forward motion ground truth is defined", "motion.npz", MOTION, step=1),
    Key("valid_bwd", "bool", (), "mask", "where the backward motion ground truth is defined", "motion.npz", MOTION, step=-1),
    Key("occlusion_fwd", "bool", (), "mask", "the point is hidden or outside the image at t+1", "motion.npz", MOTION,
        step=1, accuracy=0.01, accuracy_unit="frac"),
    Key("occlusion_bwd", "bool", (), "mask", "the point is hidden or outside the image at t-1", "motion.npz", MOTION,
        step=-1, accuracy=0.01, accuracy_unit="frac"),
)

KEYS: dict[str, Key] = {k.name: k for k in _TABLE}


def names(*stages: str) -> tuple[str, ...]:
    """Names of the keys produced by ``stages`` (all keys without arguments), in registry order."""
    bad = [s for s in stages if s not in STAGES]
    if bad:
        raise ValueError(f"unknown key stage {bad[0]!r}; use one of {STAGES}")
    return tuple(k.name for k in _TABLE if not stages or k.stage in stages)


def get(name: str) -> Key:
    """The :class:`Key` called ``name``; LfusdError naming the known keys otherwise."""
    if name not in KEYS:
        raise LfusdError(f"unknown ground-truth key {name!r}; use one of {', '.join(KEYS)}")
    return KEYS[name]


def accuracies() -> dict[str, float]:
    """The verification limit of every verified key (p99 error, in its ``accuracy_unit``)."""
    return {k.name: k.accuracy for k in _TABLE if k.accuracy is not None}


def accuracy_units() -> dict[str, str]:
    """The unit of each verified key's limit: 'rel', 'px', 'm' or 'frac'."""
    return {k.name: k.accuracy_unit for k in _TABLE if k.accuracy is not None}


def markdown_table() -> str:
    """The key table of docs/CONVENTIONS.md (a test keeps the two identical)."""
    rows = [
        "| key | shape, dtype | unit | meaning | file | produced by | verified to (p99) |",
        "|---|---|---|---|---|---|---|",
    ]
    for k in _TABLE:
        shape = ",".join(["H", "W", *map(str, k.shape)])
        acc = ""
        if k.accuracy is not None:
            value = f"{100 * k.accuracy:g} %" if k.accuracy_unit == "frac" else f"{k.accuracy:g}"
            acc = f"{value} {_ACCURACY_UNITS[k.accuracy_unit]}"
        meaning = k.meaning.replace("|", "\\|")  # a literal | would end the table cell
        rows.append(f"| `{k.name}` | {shape} {k.dtype} | {k.unit} | {meaning} | `{k.file}` | {k.stage} | {acc} |")
    return "\n".join(rows) + "\n"

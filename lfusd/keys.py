"""The ground-truth keys of an lfusd dataset: the one registry of what each key is.

Every key readable with ``Dataset.read(frame, view, key)`` has one :class:`Key` in :data:`KEYS`:
its dtype, its shape after (H, W), its unit and meaning, the per-view file it is stored in or
computed from (format version 2, :mod:`lfusd.layout`), the stage that produces it, how that file
stores it (:class:`Storage`: the one owner of each key's stored precision, which
:mod:`lfusd.data.store` encodes and checks) and, where :mod:`lfusd.truth.verify` checks it, its
accuracy. The reader, the motion derivation, the verifier, the PyTorch dataset, the exporters and
docs/CONVENTIONS.md (:func:`markdown_table`) all take their key lists from here.

Adding a key: one row in :data:`_TABLE` with its :class:`Storage`, the code that computes it (a
raw pass in ``lfusd.data.passes.read_raw``, a derived static key in ``lfusd.data.passes.DERIVED``, a
motion key in ``lfusd.truth.motion.derive_motion``) and a test; regenerate the table in
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
STATIC = "derived static"  # computed on read from one view's stored keys and the metadata
MOTION = "derived motion"  # derived from frames t-1, t, t+1 (lfusd.truth.motion), stored in motion.exr
CAST = "ray cast"  # cast through the frame's rendered triangles (geometry.npz, render-video) when gt.exr is written
STAGES = (IMAGE, RAW, STATIC, MOTION, CAST)

# Camera effects that add keys (lfusd.render.request.RenderRequest): "sensor" (--iso, lfusd.data.sensor),
# "materials" (--materials: the first surface's material flags, from the worker's MATERIAL_AOV),
# "blur" (--shutter: Cycles' motion blur in the image, its extent per pixel in the key blur),
# "defocus" (--fstop, --focus: Cycles' thin lens in the image, the circle of confusion in the key coc).
EFFECTS = ("sensor", "materials", "blur", "defocus")
# Bits of the raw `material` pass: what the first surface's material is (lfusd.render.worker.material_flags).
TRANSMISSIVE, MIRROR, EMISSIVE = 1, 2, 4
MATERIAL_MASKS = {"transmissive": TRANSMISSIVE, "mirror": MIRROR, "emissive": EMISSIVE}  # mask key -> its bit

# Units of the verification accuracies, as lfusd.truth.verify reports them.
_ACCURACY_UNITS = {"rel": "relative", "px": "px", "m": "m", "frac": "of pixels disagree"}  # for markdown_table


# How format version 2 stores a key (Storage.encoding). The precision of each lossy encoding is
# chosen so that the error it adds is at most 1/20 of the key's verification limit; the lossless
# ones cost little after compression (benchmarks/bench_storage.py measures both).
ENCODINGS = {
    "image": "half RGB as rendered, lossless",
    "float32": "float32, lossless",
    "half": "float16",  # keys in [-1, 1]: error <= 2^-12 per component
    "uint32": "uint32, lossless",
    "fixed": "float32 rounded to multiples of 2^-bits",  # absolute error <= 2^-(bits+1)
    "mask": "bit `bits` of the uint32 `masks` channel",
    "computed": "computed on read",  # from Storage.sources (and the metadata)
    "raw": "Blender's raw pass, kept only with --keep-raw",
}


@dataclass(frozen=True)
class Storage:
    """How format version 2 stores one key: the encoding (:data:`ENCODINGS`), its parameter
    ``bits`` and, for a computed key, the stored keys it is computed from."""

    encoding: str
    bits: int = 0  # 'fixed': fractional bits (values are multiples of 2**-bits); 'mask': the bit
    sources: tuple[str, ...] = ()  # 'computed': the keys it needs stored

    @property
    def error(self) -> float:
        """The largest error the encoding adds (in the key's unit; 0: lossless). Half: per component of a value in [-1, 1]."""
        return {"fixed": 2.0 ** -(self.bits + 1), "half": 2.0**-12}.get(self.encoding, 0.0)

    def describe(self, unit: str) -> str:
        """One cell of the key table: the encoding and the error it adds."""
        if self.encoding == "fixed":
            return f"float32, multiples of 2^-{self.bits} {unit} (error <= {self.error:.2g} {unit})"
        if self.encoding == "half":
            return f"float16 (error <= {self.error:.2g})"
        if self.encoding == "mask":
            return f"bit {self.bits} of `masks` (uint32)"
        if self.encoding == "computed":
            return f"computed from {', '.join(self.sources)}" if self.sources else "computed"
        return ENCODINGS[self.encoding]


@dataclass(frozen=True)
class Key:
    """One ground-truth key (see the module docstring)."""

    name: str
    dtype: str  # NumPy dtype name of the array Dataset.read returns
    shape: tuple[int, ...]  # shape after (H, W)
    unit: str
    meaning: str
    file: str  # the per-view file (lfusd.layout, format version 2) it is stored in or computed from
    stage: str  # one of STAGES
    storage: Storage = Storage("raw")  # how format version 2 stores it
    step: int = 0  # +1 / -1: describes the motion to frame t+1 / t-1 and is defined only where that frame exists
    accuracy: float | None = None  # verification limit on the p99 error (lfusd.truth.verify)
    accuracy_unit: str | None = None  # 'rel', 'px', 'm' or 'frac'
    effect: str | None = None  # the camera effect (EFFECTS) a render must turn on to make this key; None: always made

    def full_shape(self, height: int, width: int) -> tuple[int, ...]:
        """The array shape of this key in an image of ``height`` x ``width`` pixels."""
        return (height, width, *self.shape)


_RGB, _GT, _MOTION, _RAW = "rgb.exr", "gt.exr", "motion.exr", "passes.exr"  # lfusd.layout's names (keys imports no layout)
_FLOW = Storage("fixed", 8)  # 2^-9 = 0.002 px, 1/25 of the 0.05 px limit
_TABLE = (
    Key("rgb", "uint8", (3,), "sRGB", "the rendered image, 8-bit sRGB", _RGB, IMAGE,
        storage=Storage("computed", sources=("rgb_linear",))),  # rgb.png instead when rgb_linear is not asked for
    Key("rgb_linear", "float32", (3,), "linear RGB", "the rendered image, linear (scene-referred) RGB", _RGB, IMAGE,
        storage=Storage("image")),
    Key("rgb_noisy", "uint8", (3,), "sRGB", "the image a sensor would record: the sensor model of docs/CONVENTIONS.md applied to "
        "`rgb_linear` (noise, gain, vignetting, colour response, optional JPEG), reproducible for the seed", _RGB, IMAGE,
        storage=Storage("computed", sources=("rgb_linear",)), effect="sensor"),
    Key("depth", "float32", (), "m", "planar z-depth along the optical axis; `inf` where no surface", _GT, RAW,
        accuracy=1e-4, accuracy_unit="rel", storage=Storage("float32")),
    Key("normal", "float32", (3,), "unitless", "unit surface normal, world frame: the mesh's shading normal (its normals interpolated), without normal or bump maps, on the side the camera sees (negated where the ray meets a triangle's back, as Cycles does); NaN where no surface", _GT, RAW,
        storage=Storage("half")),
    Key("position", "float32", (3,), "m", "world position of the surface seen at the pixel centre; NaN where no surface", _GT, STATIC,
        storage=Storage("computed", sources=("depth",))),
    Key("instance", "int32", (), "id", "0 = background, otherwise an id listed in the object table", _GT, RAW,
        accuracy=0.0, accuracy_unit="frac", storage=Storage("uint32")),
    Key("vector", "float32", (4,), "px", "Blender's raw vector pass: X, Y = previous - current, Z, W = current - next (raster pixels, y up)",
        _RAW, RAW),
    Key("next_position", "float32", (3,), "m", "world position at t+1 of the surface point seen at t; NaN where unknown (render-video)",
        _RAW, RAW),
    Key("prev_position", "float32", (3,), "m", "world position at t-1 of the surface point seen at t; NaN where unknown (render-video)",
        _RAW, RAW),
    Key("material", "int32", (), "flags", "the first surface's material: bit 1 transmissive, 2 mirror-like, 4 emissive (render-video --materials)",
        _RAW, RAW, effect="materials"),
    Key("transmissive", "bool", (), "mask", "the first surface's material lets light through (opacity or alpha below 1, transmission, "
        "a glass or transparent BSDF): the image shows what lies behind it (render-video --materials)", _GT, RAW,
        storage=Storage("mask", 5), effect="materials"),
    Key("mirror", "bool", (), "mask", "the first surface's material is mirror-like: roughness at most 0.2 and metallic at least 0.5 "
        "or specular at least 0.5: the image shows reflections (render-video --materials)", _GT, RAW, storage=Storage("mask", 6),
        effect="materials"),
    Key("emissive", "bool", (), "mask", "the first surface's material emits light (render-video --materials)", _GT, RAW,
        storage=Storage("mask", 7), effect="materials"),
    Key("depth_behind", "float32", (), "m", "planar z-depth of the first surface along the pixel's ray that is not transmissive: "
        "`depth` where the first surface is opaque, what lies behind where it is transmissive; `inf` where none "
        "(render-video --materials)", _GT, CAST, storage=Storage("float32"), effect="materials"),
    Key("semantic", "int32", (), "id", "class id listed in the class table (0 = unlabelled)", _GT, STATIC,
        storage=Storage("computed", sources=("instance",))),
    Key("disparity", "float32", (), "px", "pixels per unit baseline step, d = f_px * b / z (planar, parallel rigs; through a lens (--lens), the column shift to the view moved one baseline, CONVENTIONS \"Lens distortion\", NaN past its fold); 0 where no surface",
        _GT, STATIC, storage=Storage("computed", sources=("depth",))),
    Key("depth_euclidean", "float32", (), "m",
        "distance along the pixel's ray from the camera centre to the surface, depth * ||K^-1 [u, v, 1]||; `inf` where no surface",
        _GT, STATIC, storage=Storage("computed", sources=("depth",))),
    Key("coc", "float32", (), "px", "diameter of the circle of confusion: the disc the lens spreads the pixel's surface point over "
        "(render-video --fstop N --focus S), f_px * (f / N) * |1/S - 1/depth| (Cycles' thin lens, f the focal length); "
        "through a lens (--lens), the largest diameter of the ellipse the model images that disc as (f_px then the largest "
        "singular value of its Jacobian at the pixel, CONVENTIONS \"Lens distortion\")",
        _GT, STATIC, storage=Storage("computed", sources=("depth",)), effect="defocus"),
    Key("flow_fwd", "float32", (2,), "px", "(du, dv): the point at (u, v) in frame t is at (u+du, v+dv) in t+1", _MOTION, MOTION,
        step=1, accuracy=0.05, accuracy_unit="px", storage=_FLOW),
    Key("flow_bwd", "float32", (2,), "px", "(du, dv): the point at (u, v) in frame t is at (u+du, v+dv) in t-1", _MOTION, MOTION,
        step=-1, accuracy=0.05, accuracy_unit="px", storage=_FLOW),
    # 2^-18 m = 3.8 um: 1/20 of verify's limit (1e-3 of the object's size) down to 7.6 cm objects
    Key("scene_flow", "float32", (3,), "m", "world-frame displacement of the surface point seen at (u, v), t -> t+1", _MOTION, MOTION,
        step=1, accuracy=1e-3, accuracy_unit="m", storage=Storage("fixed", 17)),
    Key("disparity_change", "float32", (), "px", "disparity of that point at t+1 minus its disparity at t", _MOTION, MOTION,
        step=1, accuracy=0.05, accuracy_unit="px", storage=_FLOW),
    Key("blur", "float32", (), "px", "length of the image-space path of the surface point seen at (u, v) over the shutter "
        "(t - s/2 to t + s/2, render-video --shutter s): how far Cycles' motion blur smears it, the point and the camera moving "
        "linearly between their poses at t-1, t and t+1; 0 where no surface; NaN where t-1 or t+1 is not in the dataset or the "
        "point's motion is unknown", _MOTION, MOTION, storage=_FLOW, effect="blur"),
    Key("valid_fwd", "bool", (), "mask", "where the forward motion ground truth is defined", _MOTION, MOTION, step=1,
        storage=Storage("mask", 0)),
    Key("valid_bwd", "bool", (), "mask", "where the backward motion ground truth is defined", _MOTION, MOTION, step=-1,
        storage=Storage("mask", 1)),
    Key("occlusion_fwd", "bool", (), "mask", "the point is hidden or outside the image at t+1", _MOTION, MOTION,
        step=1, accuracy=0.0, accuracy_unit="frac", storage=Storage("mask", 2)),
    Key("occlusion_bwd", "bool", (), "mask", "the point is hidden or outside the image at t-1", _MOTION, MOTION,
        step=-1, accuracy=0.0, accuracy_unit="frac", storage=Storage("mask", 3)),
    Key("mixed", "bool", (), "mask", "the pixel's footprint holds more than one surface or motion: the rays through its four corners "
        "(at +-1/2 px) see different instances, depths more than 1 % apart, or forward flows more than 0.5 px apart, or a "
        "discontinuity edge of the triangles (a boundary, a silhouette, an edge between two instances) crosses its square "
        "not behind what the corners see, however thin the structure "
        "(render-video; the edge and fine-structure mask of HCI and Spring)", _MOTION, MOTION, storage=Storage("mask", 4)),
)

KEYS: dict[str, Key] = {k.name: k for k in _TABLE}
# The raw passes gt.exr stores: what a view's static keys come from before its gt.exr is written.
GT_RAW = tuple(k.name for k in _TABLE if k.stage == RAW and k.file == _GT)


@dataclass(frozen=True)
class RawPass:
    """One of Blender's data passes in a view's ``passes.exr``: the raw-pass contract between the
    render worker (lfusd.render.worker turns it on) and the reader (lfusd.data.passes.read_raw).

    ``key``: the array the reader returns; ``layer``: the pass's name in Blender's multilayer EXR
    (a render pass, or the name of an AOV of the data material); ``channels``: the channels read,
    in order (``<layer>.<c>`` of a render pass; an AOV is one colour group whose first
    ``len(channels)`` components are read); ``dtype``: of the array returned; ``switch``: the
    ViewLayer property that turns a render pass on (None for an AOV); ``neighbour``: an AOV's
    frame, ``next`` (t+1) or ``prev`` (t-1), whose vertex positions the mesh attribute
    ``lfusd_<neighbour>`` carries (render-video only); ``required``: every data render writes it
    (the others: render-video's AOVs, and the vector pass, which format version 1 datasets may lack).
    """

    key: str
    layer: str
    channels: str
    dtype: str
    switch: str | None = None
    neighbour: str | None = None
    required: bool = True
    aov: bool = False  # an AOV of the data material (a COLOR group), not a render pass

    @property
    def channel_names(self) -> tuple[str, ...]:
        """The EXR channel names of a render pass, without the view layer's prefix: ``Depth.Z``."""
        return tuple(f"{self.layer}.{c}" for c in self.channels)


RAW_PASSES = (
    RawPass("depth", "Depth", "Z", "float32", "use_pass_z"),  # BACKGROUND_DEPTH or beyond where no surface
    RawPass("normal", "Normal", "XYZ", "float32", "use_pass_normal"),
    RawPass("position", "Position", "XYZ", "float32", "use_pass_position"),
    RawPass("instance", "Object Index", "X", "int32", "use_pass_object_index"),  # a float holding the pass index
    RawPass("vector", "Vector", "XYZW", "float32", "use_pass_vector", required=False),
    RawPass("next_position", "next_position", "XYZ", "float32", neighbour="next", required=False, aov=True),  # a COLOR AOV (RGBA)
    RawPass("prev_position", "prev_position", "XYZ", "float32", neighbour="prev", required=False, aov=True),
    RawPass("material", "lfusd_material", "X", "int32", required=False, aov=True),  # --materials: the flags as a float, in R
)
RAW_PASS: dict[str, RawPass] = {p.key: p for p in RAW_PASSES}
PASS_SWITCHES = tuple(p.switch for p in RAW_PASSES if p.switch)  # the ViewLayer switches of the data render
MOTION_AOVS = tuple(p for p in RAW_PASSES if p.neighbour)  # rendered only by render-video
MATERIAL_AOV = RAW_PASS["material"]  # rendered only with --materials


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


def stored(wanted) -> tuple[str, ...]:
    """The keys format version 2 stores so that every key of ``wanted`` can be read: those stored
    directly, and the sources of the computed ones (registry order). ``rgb`` without ``rgb_linear``
    is stored itself (rgb.png)."""
    wanted = set(wanted)
    need = {n for n in wanted if KEYS[n].storage.encoding != "computed"}
    need |= {s for n in wanted for s in KEYS[n].storage.sources if n != "rgb"}
    if "rgb" in wanted:
        need.add("rgb_linear" if "rgb_linear" in wanted else "rgb")
    return tuple(k.name for k in _TABLE if k.name in need)


_AOV_KEYS = tuple(p.key for p in MOTION_AOVS)


_EFFECT_OPTION = {"sensor": "--iso", "materials": "--materials", "blur": "--shutter", "defocus": "--fstop"}


def check_wanted(wanted, motion: bool, keep_raw: bool, effects=()) -> tuple[str, ...]:
    """The keys a render writes, validated (``--keys``): LfusdError in one line naming the first
    unknown key, a motion key without render-video, a raw pass without ``--keep-raw`` or a key of a
    camera effect (:data:`EFFECTS`) the render does not turn on (``effects``).
    ``wanted`` None: every key the render makes (raw passes with ``keep_raw``, effects' keys with them)."""
    effects = set(effects)
    if wanted is None:
        return tuple(k.name for k in _TABLE if (motion or k.stage != MOTION) and (keep_raw or k.storage.encoding != "raw")
                     and (motion or k.name not in _AOV_KEYS) and (k.effect is None or k.effect in effects))
    for name in wanted:
        k = get(name)
        if k.effect is not None and k.effect not in effects:
            raise LfusdError(f"--keys {name}: made only with {_EFFECT_OPTION[k.effect]}; add it or drop the key")
        if k.stage == MOTION and not motion:
            raise LfusdError(f"--keys {name}: motion keys need 'lfusd render-video'; drop it or render a video")
        if k.storage.encoding == "raw" and not keep_raw:
            raise LfusdError(f"--keys {name}: a raw pass, kept only with --keep-raw; add --keep-raw or drop it")
        if name in _AOV_KEYS and not motion:
            raise LfusdError(f"--keys {name}: a motion AOV, rendered only by 'lfusd render-video'; drop it or render a video")
    return tuple(k.name for k in _TABLE if k.name in set(wanted))


def accuracies() -> dict[str, float]:
    """The verification limit of every verified key (p99 error, in its ``accuracy_unit``)."""
    return {k.name: k.accuracy for k in _TABLE if k.accuracy is not None}


def accuracy_units() -> dict[str, str]:
    """The unit of each verified key's limit: 'rel', 'px', 'm' or 'frac'."""
    return {k.name: k.accuracy_unit for k in _TABLE if k.accuracy is not None}


def markdown_table() -> str:
    """The key table of docs/CONVENTIONS.md (a test keeps the two identical)."""
    rows = [
        "| key | shape, dtype | unit | meaning | file | produced by | stored as | verify limit (per pixel) |",
        "|---|---|---|---|---|---|---|---|",
    ]
    for k in _TABLE:
        shape = ",".join(["H", "W", *map(str, k.shape)])
        acc = ""
        if k.accuracy is not None:
            value = f"{100 * k.accuracy:g} %" if k.accuracy_unit == "frac" else f"{k.accuracy:g}"
            acc = f"{value} {_ACCURACY_UNITS[k.accuracy_unit]}"
        meaning = k.meaning.replace("|", "\\|")  # a literal | would end the table cell
        rows.append(f"| `{k.name}` | {shape} {k.dtype} | {k.unit} | {meaning} | `{k.file}` | {k.stage} | {k.storage.describe(k.unit)} | {acc} |")
    return "\n".join(rows) + "\n"

"""Export a dataset as WebDataset tar shards with Croissant metadata (``lfusd export webdataset``);
:mod:`lfusd.exports.hf` adds a Hugging Face dataset card whose YAML header points
``datasets.load_dataset`` at the shards (``lfusd export hf``).

One sample per frame x view: a sample is what a model reads at a time (one image with its ground
truth), it stays small whatever the grid (every key of a render-video is about 71 bytes per pixel as
.npy: a 9x9 frame at 1024x1024 would be a 6 GB sample), shuffling mixes views and frames, and the views of one frame are consecutive in a
shard with ``frame``, ``row`` and ``col`` in their ``json``, so a loader can group them again.

Shards are ``shards/<scene>-<rig>-<n:06d>-<sha256[:12]>.tar``: the content hash keeps mlcroissant,
which caches an archive's extraction by its URL, from reading an older export of the same name.
Sample ``<rig>_f<frame:06d>_<row:02d>_<col:02d>`` (WebDataset splits names at the first dot, so
keys hold none):

- ``rgb.png``: the 8-bit sRGB image (lossless PNG);
- ``<key>.npy``: every other key the dataset stores (:func:`lfusd.keys.stored`), exactly as
  ``Dataset.read`` returns it (NumPy .npy: dtype, shape, NaN and inf kept);
- ``json``: frame, row, col, rig, scene, K, cam_to_world, baseline, the view's grid offsets.

``metadata.json`` is Croissant 1.0 (validated with mlcroissant): one FileObject per shard (with
its sha256), one FileSet per key inside the shards and one RecordSet per key whose field
descriptions (dtype, shape, unit, meaning) come from :mod:`lfusd.keys`. ``.npy`` files are
declared ``text/plain`` because that is the format whose raw bytes mlcroissant returns
(``fileProperty: content``); ``numpy.load(io.BytesIO(content))`` decodes them. Verification
certificate of the rig (lfusd verify's figures in the manifest, still bound to the content:
:mod:`lfusd.data.certificate`) goes into the description and into ``lfusd_verification.json``;
nothing outside the dataset's folder is read.
``lfusd_rig.json`` holds the rig's name and spec and ``objects.json`` the dataset's object table, so
that :class:`lfusd.data.shards.ShardDataset` reads the export as a dataset (the training loader's
items, derived keys included).
"""

from __future__ import annotations

import datetime
import io
import json
import logging
from pathlib import Path

import numpy as np

from ..data import formats
from .. import keys as keyreg
from .. import layout
from ..files import sha256_of
from .common import frames_of, new_dest
from .registry import TEXT, Option, register

log = logging.getLogger(__name__)

SHARD_MAX_BYTES = 1_000_000_000  # a new shard past 1 GB (WebDataset's usual size)
SHARD_MAX_SAMPLES = 10_000
SHARDS = "shards"
CROISSANT = "metadata.json"
CARD = "README.md"
VERIFICATION = "lfusd_verification.json"
RIG = "lfusd_rig.json"  # the rig's name and spec, so that lfusd.data.shards reads the shards as a dataset


def sample_key(rig: str, frame: int, view) -> str:
    """The WebDataset key of one frame and view: ``main_f000001_04_04`` (dots replaced)."""
    return f"{rig.replace('.', '-')}_f{int(frame):06d}_{int(view[0]):02d}_{int(view[1]):02d}"


def exported_keys(ds) -> list[str]:
    """The keys a sample holds besides ``rgb``: those the dataset's manifest says it stores (the
    keys its render was asked for, else every key that render makes: motion keys only for a
    render-video), never guessed from what one view happens to read; a view that cannot give one
    of them is an error when its sample is written."""
    keys = getattr(ds, "keys", None)
    if keys is None:
        record = getattr(ds, "record", None)  # the typed manifest of a Dataset (lfusd.data.folder.Manifest)
        keys = keyreg.check_wanted(None, motion=record.settings.motion if record is not None else True, keep_raw=False)
    return [k for k in keyreg.stored(keys) if k != "rgb" and keyreg.get(k).storage.encoding != "raw"]


# derived keys a sample holds too (the learning targets), each computed from a stored key
DERIVED_IN_SHARDS = {"disparity": "depth", "semantic": "instance"}


def shard_keys(ds) -> list[str]:
    """The ``<key>.npy`` files of a sample: the stored keys (:func:`exported_keys`), plus
    ``disparity`` and ``semantic`` where the keys they are computed from are there."""
    names = exported_keys(ds)
    return names + [k for k, src in DERIVED_IN_SHARDS.items() if src in names and k not in names]


def _npy(a: np.ndarray) -> bytes:
    buf = io.BytesIO()
    np.save(buf, np.asarray(a), allow_pickle=False)
    return buf.getvalue()


def _sample_meta(ds, frame: int, view) -> dict:
    sx, sy = ds.rig.offsets(tuple(view))
    return {"scene": Path(getattr(ds, "root", "scene")).name, "rig": getattr(ds, "rig_name", "rig"), "frame": int(frame),
            "row": int(view[0]), "col": int(view[1]), "width": int(ds.rig.width), "height": int(ds.rig.height),
            "K": np.asarray(ds.intrinsics(view), float).tolist(), "cam_to_world": np.asarray(ds.cam_to_world(frame, view), float).tolist(),
            "baseline_m": float(ds.baseline), "offset_x": float(sx), "offset_y": float(sy), "dist": _dist(ds, view)}


def _dist(ds, view) -> list[float]:
    """The view's lens distortion as OpenCV's distCoeffs (k1, k2, p1, p2, k3); zeros for a pinhole."""
    d = ds.distortion(tuple(view)) if getattr(ds, "distorted", False) else None
    return [0.0] * 5 if d is None else d.coeffs.tolist()


def verification_figures(ds) -> dict:
    """The dataset's verification certificate of the exported rig (lfusd verify's figures, in its
    manifest), only where its binding to the content still holds (lfusd.data.certificate.certified).
    Reads nothing outside the dataset's folder."""
    from ..data.certificate import certified

    root = getattr(ds, "root", None)
    if root is None or not (Path(root) / layout.MANIFEST).is_file():
        return {}  # a reader made in memory: no certificate
    rig = getattr(ds, "rig_name", None)
    cert = certified(root, rig)
    return {"certificate": cert} if cert else {}


def _field_description(name: str) -> str:
    k = keyreg.get(name)
    shape = ",".join(["H", "W", *map(str, k.shape)])
    return f"{k.meaning} (unit: {k.unit}; array {shape} {k.dtype}; stored as {k.storage.describe(k.unit)} in lfusd)"


def croissant(ds, dest: Path, shards: list[Path], names: list[str], verification: dict, license: str | None = None) -> dict:
    """The Croissant 1.0 JSON-LD of an export (see the module docstring). Only what lfusd knows
    goes in: no URL, and a license only when given (the data's owner decides it)."""
    scene = Path(getattr(ds, "root", "scene")).name
    rig = ds.rig
    desc = (f"lfusd light-field video dataset '{scene}', rig '{getattr(ds, 'rig_name', 'rig')}': {rig.rows}x{rig.cols} views at "
            f"{rig.width}x{rig.height} px, frames {ds.frames[0]}..{ds.frames[-1]}, baseline {float(rig.baseline):g} m. One WebDataset "
            f"sample per frame and view: rgb.png, <key>.npy per ground-truth key, json (K, cam_to_world, frame, row, col). "
            f"Conventions: metres, seconds; OpenCV camera frame; world Z-up.")
    if verification:
        desc += " Verification: " + json.dumps(verification, sort_keys=True)
    files = [{"@type": "cr:FileObject", "@id": f"shard-{i}", "name": f"shard-{i}", "contentUrl": p.relative_to(dest).as_posix(),
              "encodingFormat": "application/x-tar", "sha256": sha256_of(p), "contentSize": f"{p.stat().st_size} B"}
             for i, p in enumerate(shards)]
    shard_ids = [{"@id": f["@id"]} for f in files]
    if (dest / layout.OBJECTS).is_file():  # the tables `instance` and `semantic` index, beside the shards
        p = dest / layout.OBJECTS
        files.append({"@type": "cr:FileObject", "@id": "objects", "name": "objects", "contentUrl": layout.OBJECTS,
                      "encodingFormat": "application/json", "sha256": sha256_of(p), "contentSize": f"{p.stat().st_size} B",
                      "description": "the class table (semantic id -> class name) and the instance table (instance id -> prim path, class)"})
    parts = [("rgb", "rgb.png", "image/png", "sc:ImageObject", _field_description("rgb") + "; PNG"),
             ("meta", "json", "application/json", "sc:Text", "per-sample metadata: scene, rig, frame, row, col, width, height, K (3x3 px), "
              "cam_to_world (4x4 OpenCV camera to world, m), baseline_m, offset_x, offset_y (grid offsets in baselines)")]
    parts += [(n, f"{n}.npy", "text/plain", "sc:Text", _field_description(n) + "; NumPy .npy bytes: numpy.load(io.BytesIO(content))")
              for n in names]
    sets, records = [], []
    for name, ext, enc, dtype, text in parts:
        fs = f"files-{name}"
        sets.append({"@type": "cr:FileSet", "@id": fs, "name": fs, "containedIn": shard_ids, "encodingFormat": enc, "includes": f"*.{ext}"})
        src = {"fileSet": {"@id": fs}}
        records.append({"@type": "cr:RecordSet", "@id": name, "name": name, "description": text, "field": [
            {"@type": "cr:Field", "@id": f"{name}/sample", "name": "sample", "description": "the WebDataset key: <rig>_f<frame>_<row>_<col>",
             "dataType": "sc:Text", "source": src | {"extract": {"fileProperty": "filename"}, "transform": {"regex": r"^([^.]+)\..*$"}}},
            {"@type": "cr:Field", "@id": f"{name}/{name}", "name": name, "description": text, "dataType": dtype,
             "source": src | {"extract": {"fileProperty": "content"}}},
        ]})
    doc = {
        "@context": _CONTEXT,
        "@type": "sc:Dataset",
        "conformsTo": "http://mlcommons.org/croissant/1.0",
        "name": f"{scene}-{getattr(ds, 'rig_name', 'rig')}".replace(" ", "_"),
        "description": desc,
        "version": "1.0.0",  # the export's; raise it when publishing a changed dataset
        "citeAs": f"{scene}: a light-field video dataset rendered with lfusd",
        "datePublished": datetime.date.today().isoformat(),  # the export's date
        "distribution": files + sets,
        "recordSet": records,
    }
    if license:
        doc["license"] = license
    return doc


# the per-sample json (_sample_meta) as a Hugging Face struct feature
_META_FEATURES = (("scene", "string"), ("rig", "string"), ("frame", "int64"), ("row", "int64"), ("col", "int64"),
                  ("width", "int64"), ("height", "int64"), ("K", "matrix"), ("cam_to_world", "matrix"),
                  ("baseline_m", "float64"), ("offset_x", "float64"), ("offset_y", "float64"), ("dist", "vector"))


def hf_features(ds, names: list[str]) -> str:
    """The card's ``dataset_info.features`` (YAML): every ``<key>.npy`` as a fixed-shape array of its
    dtype (``array2_d`` / ``array3_d``), so ``datasets`` stores it as one Arrow tensor rather than
    nested lists (far faster to read) and hands ``instance`` back as int32, not int64."""
    h, w = int(ds.rig.height), int(ds.rig.width)
    lines = ["  features:", "  - name: __key__", "    dtype: string", "  - name: __url__", "    dtype: string",
             "  - name: rgb.png", "    dtype: image", "  - name: json", "    struct:"]
    for name, kind in _META_FEATURES:
        shape = {"matrix": "      list:\n        list: float64", "vector": "      list: float64"}
        lines += [f"    - name: {name}", shape.get(kind, f"      dtype: {kind}")]
    for n in names:
        k = keyreg.get(n)
        shape = [h, w, *k.shape]
        lines += [f"  - name: {n}.npy", "    dtype:", f"      array{len(shape)}_d:", "        shape:"]
        lines += [f"        - {d}" for d in shape]
        lines += [f"        dtype: {k.dtype}"]
    return "\n".join(lines) + "\n"


def hf_card(ds, croissant_doc: dict, license: str | None = None, names: list[str] | None = None) -> str:
    """README.md of a Hugging Face dataset folder: YAML configs pointing at the shards, the
    features of every column (:func:`hf_features`), and the description."""
    info = f"dataset_info:\n{hf_features(ds, names)}" if names is not None else ""
    return (f"---\nlicense: {license or 'unknown'}\n{info}configs:\n- config_name: default\n  data_files:\n  - split: train\n"
            f"    path: {SHARDS}/*.tar\ntags:\n- light-field\n- optical-flow\n- scene-flow\n- depth\n---\n\n"
            f"# {croissant_doc['name']}\n\n{croissant_doc['description']}\n\nCroissant metadata: `{CROISSANT}`; `{layout.OBJECTS}` "
            "(where present) maps `instance` ids to prim paths and classes and `semantic` ids to class names. Load with "
            "`datasets.load_dataset(PATH)` (the features above: every array keeps its shape and dtype; "
            "`.with_format(\"numpy\", dtype=None)` keeps `instance` int32, which `datasets`' numpy format otherwise widens to int64) "
            "or `datasets.load_dataset(\"webdataset\", data_files={\"train\": \"shards/*.tar\"})`.\n")


LICENSE = Option("--license", "license", TEXT, "the data's license (SPDX id or URL) for the metadata (default: none claimed)")


@register("webdataset", "tar shards of one sample per frame and view, Croissant metadata.json", options=(LICENSE,), unit="shard")
def export_webdataset(ds, dest, frame: int | None = None, views=None, hf: bool = False, license: str | None = None) -> list[Path]:
    """Write tar shards of one sample per frame x view under ``dest/shards`` and ``dest/metadata.json``
    (and with ``hf`` a dataset card ``README.md``); returns the shards. ``license``: the data's
    license (an SPDX id or URL) for the metadata; none is claimed without it."""
    frames = frames_of(ds, frame)
    views = [tuple(v) for v in (views or ds.views)]
    names = shard_keys(ds)
    dest = new_dest(dest)
    (dest / SHARDS).mkdir()
    rig = getattr(ds, "rig_name", "rig")
    stem = f"{Path(getattr(ds, 'root', 'scene')).name}-{rig}"
    with _ShardWriter(dest / SHARDS, stem) as sink:
        for t in frames:
            for v in views:
                files = {"rgb.png": formats.encode_png(ds.read(t, v, "rgb")), "json": json.dumps(_sample_meta(ds, t, v)).encode()}
                for n in names:
                    files[f"{n}.npy"] = _npy(ds.read(t, v, n))
                sink.write(sample_key(rig, t, v), files)
    shards = []
    for p in sorted((dest / SHARDS).glob("*.tar")):
        # the content's hash in the name: mlcroissant caches an archive's extraction by its URL alone,
        # so a re-export under the old name would read the old samples
        shards.append(p.rename(p.with_name(f"{p.stem}-{sha256_of(p)[:12]}.tar")))
    verification = verification_figures(ds)
    objects = Path(getattr(ds, "root", "")) / layout.OBJECTS
    if objects.is_file():  # the class and instance tables that `instance` and `semantic` index
        (dest / layout.OBJECTS).write_bytes(objects.read_bytes())
    doc = croissant(ds, dest, shards, names, verification, license)
    (dest / CROISSANT).write_text(json.dumps(doc, indent=1))
    if verification:
        (dest / VERIFICATION).write_text(json.dumps(verification, indent=1))
    (dest / RIG).write_text(json.dumps({"rig": rig, "spec": ds.rig.to_dict()}, indent=1))
    if hf:
        (dest / CARD).write_text(hf_card(ds, doc, license, names))
    log.info("wrote %d samples in %d shard(s) to %s", len(frames) * len(views), len(shards), dest)
    return shards


class _ShardWriter:
    """WebDataset shards ``<stem>-000000.tar``, ...: a sample's files ``<key>.<ext>`` consecutive in
    one tar, a new shard past :data:`SHARD_MAX_BYTES` or :data:`SHARD_MAX_SAMPLES` (the tar
    format WebDataset reads; written with the standard library so exporting loads no torch)."""

    def __init__(self, folder: Path, stem: str):
        self.folder, self.stem, self.index, self.tar, self.count, self.size = folder, stem, -1, None, 0, 0

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        if self.tar is not None:
            self.tar.close()

    def write(self, key: str, files: dict[str, bytes]) -> None:
        import tarfile

        nbytes = sum(len(b) for b in files.values())
        if self.tar is None or self.count >= SHARD_MAX_SAMPLES or (self.count and self.size + nbytes > SHARD_MAX_BYTES):
            if self.tar is not None:
                self.tar.close()
            self.index += 1
            self.tar = tarfile.open(self.folder / f"{self.stem}-{self.index:06d}.tar", "w", format=tarfile.USTAR_FORMAT)
            self.count = self.size = 0
        for ext, data in files.items():
            info = tarfile.TarInfo(f"{key}.{ext}")
            info.size, info.mode, info.mtime = len(data), 0o444, 0  # mtime 0: the same data gives the same shard
            self.tar.addfile(info, io.BytesIO(data))
        self.count += 1
        self.size += nbytes


_CONTEXT = {
    "@language": "en",
    "@vocab": "https://schema.org/",
    "citeAs": "cr:citeAs",
    "equivalentProperty": "cr:equivalentProperty",
    "samplingRate": "cr:samplingRate",
    "column": "cr:column",
    "conformsTo": "dct:conformsTo",
    "cr": "http://mlcommons.org/croissant/",
    "rai": "http://mlcommons.org/croissant/RAI/",
    "data": {"@id": "cr:data", "@type": "@json"},
    "dataType": {"@id": "cr:dataType", "@type": "@vocab"},
    "dct": "http://purl.org/dc/terms/",
    "examples": {"@id": "cr:examples", "@type": "@json"},
    "extract": "cr:extract",
    "field": "cr:field",
    "fileProperty": "cr:fileProperty",
    "fileObject": "cr:fileObject",
    "fileSet": "cr:fileSet",
    "format": "cr:format",
    "includes": "cr:includes",
    "isLiveDataset": "cr:isLiveDataset",
    "jsonPath": "cr:jsonPath",
    "key": "cr:key",
    "md5": "cr:md5",
    "parentField": "cr:parentField",
    "path": "cr:path",
    "recordSet": "cr:recordSet",
    "references": "cr:references",
    "regex": "cr:regex",
    "repeated": "cr:repeated",
    "replace": "cr:replace",
    "sc": "https://schema.org/",
    "separator": "cr:separator",
    "source": "cr:source",
    "subField": "cr:subField",
    "transform": "cr:transform",
}

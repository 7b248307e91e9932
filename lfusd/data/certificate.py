"""The verification certificate, bound to the content it certifies.

``lfusd verify``'s figures go into the manifest (``certificate``: per rig, what
:meth:`lfusd.truth.verify.VerifyReport.certificate` returns) with a ``binding``: the verifier's
version and one sha256 over what the figures speak of, the rig's settings, its frames'
``frame.json``, the object table and every view's completion record (which holds the sha256 of each
of the view's files, :mod:`lfusd.data.integrity`). Before a certificate is republished (an
export's metadata, a recipe's card) :func:`certified` checks that binding again, and each file
against its record, so a certificate pasted into a manifest, copied from another dataset or left
from before the files changed is not passed on as proof. Without a secret nobody can tell lfusd's
own digest from one an attacker computed the same way: the binding proves that the figures belong
to this content, not who measured them. No pxr, bpy or torch.
"""

from __future__ import annotations

import hashlib
import json
import logging
from pathlib import Path

from .. import __version__, layout
from ..layout import frame_dir, view_key

log = logging.getLogger(__name__)

BINDING = "binding"
VERIFIER = f"lfusd {__version__}"  # the verifier that measured the figures (its thresholds and rules are in them too)


def _file_sha256(path: Path) -> str | None:
    try:
        return hashlib.sha256(path.read_bytes()).hexdigest()
    except OSError:
        return None


def content_digest(root: str | Path, rig: str, manifest=None) -> str:
    """sha256 over what a certificate of ``rig`` speaks of (see the module docstring): cheap to
    compute (records and metadata, not pixels); :func:`certified` checks the files against the records."""
    from .folder import read_manifest
    from .integrity import read_record

    root = Path(root)
    manifest = manifest or read_manifest(root)
    spec = manifest.rig_spec(rig, root / layout.MANIFEST)
    h = hashlib.sha256()

    def add(*parts) -> None:
        h.update(json.dumps(parts, sort_keys=True, default=str).encode())
        h.update(b"\n")

    add("rig", rig, manifest.settings.to_dict().get("rigs", {}).get(rig), manifest.stage.get("sha256"),
        {k: v for k, v in manifest.settings.to_dict().items() if k != "rigs"})
    add("objects", _file_sha256(root / layout.OBJECTS))
    for f in manifest.frames:
        fd = frame_dir(root, rig, f)
        add("frame", int(f), _file_sha256(fd / layout.FRAME_META))
        for v in spec.views:
            record = read_record(fd / view_key(v))
            add("view", view_key(v), (record or {}).get("files"))
    return h.hexdigest()


def camera_effects(settings: dict) -> dict:
    """The camera effects a render turned on (docs/CONVENTIONS.md, "Camera effects"), by name with their
    settings, from the manifest's ``settings``: motion_blur (--shutter), defocus (--fstop, --focus),
    sensor_noise (--iso ...), material_masks (--materials), lens_distortion (--lens ...); {} for none."""
    s = settings.to_dict() if hasattr(settings, "to_dict") else dict(settings or {})
    lens = s.get("lens")
    found = {
        "motion_blur": {"shutter": s["shutter"]} if s.get("shutter") else None,
        "defocus": s.get("defocus") or None,
        "sensor_noise": s.get("sensor") or None,
        "material_masks": True if s.get("materials") else None,
        "lens_distortion": {k: lens[k] for k in ("model", "seed", "spread") if k in lens} if isinstance(lens, dict) else None,
    }
    return {name: value for name, value in found.items() if value is not None}


def bind(root: str | Path, rig: str, figures: dict) -> dict:
    """``figures`` (a rig's verify certificate) with the camera effects it was verified with (:func:`camera_effects`)
    and the binding to the dataset's current content (whose settings hold those effects)."""
    from .folder import read_manifest

    effects = camera_effects(read_manifest(Path(root)).settings)
    return {**{k: v for k, v in figures.items() if k != BINDING}, "camera_effects": effects,
            BINDING: {"verifier": VERIFIER, "content_sha256": content_digest(root, rig)}}


def certified(root: str | Path, rig: str | None = None) -> dict:
    """The certificates of the dataset in ``root`` (of ``rig``, or of every rig) whose binding
    still holds: {rig: figures}. A certificate without a binding, bound to other content, or whose
    files no longer match their records is left out, with a warning. Reads the files' digests
    (as ``lfusd verify --integrity``)."""
    from .folder import read_manifest
    from .integrity import check_dataset

    root = Path(root)
    manifest = read_manifest(root)
    certs = manifest.certificate if isinstance(manifest.certificate, dict) else {}
    out = {}
    for name, figures in certs.items():
        if (rig is not None and name != rig) or name not in manifest.rigs:
            continue
        binding = figures.get(BINDING) if isinstance(figures, dict) else None
        why = None
        if not isinstance(binding, dict) or not isinstance(binding.get("verifier"), str):
            why = "it is bound to no content"
        elif binding.get("content_sha256") != content_digest(root, name, manifest):
            why = "it was made for other content"
        elif "camera_effects" in figures and figures["camera_effects"] != camera_effects(manifest.settings):
            why = "the camera effects it names are not the dataset's"
        elif check_dataset(root, name)[1]:
            why = "files it covers no longer match their records"
        if why:
            log.warning("%s: the verification certificate of rig %s is not passed on: %s; run 'lfusd verify' again",
                        root / layout.MANIFEST, name, why)
            continue
        out[name] = {**figures, "camera_effects": camera_effects(manifest.settings)}  # named by the settings it is bound to
    return out
